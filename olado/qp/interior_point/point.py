"""Points and residuals of the interior-point QP: an iterate or a direction is one flat vector
with views X, U, lam, nu (the primal and equality-multiplier parts s, p of paper 001 (16)-(17))
and tl, tu, zl, zu (the slacks w and multipliers lambda of the two sides of every box, (18)-(20));
a residual vector has the views of the equations of the Newton system (22).
"""

from __future__ import annotations

import math

import numpy as np

from ...linalg.backend import RHS, Solution
from .bundles import DUAL_FIELDS, PointArrays, Residuals, Slacks


class _Layout:
    """Where the fields of a bundle (a namedtuple class of bundles.py) lie in one flat vector:
    ``spans`` {name: (start, stop, shape)} in the bundle's field order, ``size`` the vector's
    length."""

    __slots__ = ("bundle", "spans", "size", "_cuts")

    def __init__(self, bundle, **shapes):
        if tuple(shapes) != bundle._fields:
            raise ValueError(f"layout of {bundle.__name__}: fields {tuple(shapes)}, expected {bundle._fields}")
        self.bundle, self.spans, o = bundle, {}, 0
        for name, shape in shapes.items():
            size = math.prod(shape)
            self.spans[name] = (o, o + size, shape)
            o += size
        self.size = o
        self._cuts = tuple((slice(a, b), None if len(shape) == 1 else shape) for a, b, shape in self.spans.values())

    @classmethod
    def of(cls, bundle, **shapes):
        """The layout of ``bundle`` for these shapes: made once per (bundle, shapes) and shared
        (a layout is never changed after construction; the QPs of one problem have the same
        shapes in every SQP iteration)."""
        key = (bundle, tuple(shapes.items()))
        layout = _LAYOUTS.get(key)
        if layout is None:
            if len(_LAYOUTS) >= 64:
                _LAYOUTS.clear()
            layout = _LAYOUTS[key] = cls(bundle, **shapes)
        return layout

    def views(self, v):
        """The fields' views into the flat vector v (1-d fields as slices), a plain tuple in the
        bundle's field order (what the kernels take)."""
        return tuple([v[sl] if shape is None else v[sl].reshape(shape) for sl, shape in self._cuts])

    def span(self, first, last):
        """The slice of the flat vector from field ``first`` to field ``last`` (inclusive)."""
        return slice(self.spans[first][0], self.spans[last][1])

    def mask(self, names):
        """Boolean mask of the flat vector: True on the fields ``names``."""
        out = np.zeros(self.size, dtype=np.bool_)
        for name in names:
            a, b, _ = self.spans[name]
            out[a:b] = True
        return out


_LAYOUTS: dict = {}   # _Layout.of


# the complementarity pairs are the fields tl..zu of a point, in the order of bundles.Slacks, and
# the arrays of a KKT solution its first fields X..nu, in the order of backend.Solution
_SLACKS = slice(PointArrays._fields.index(Slacks._fields[0]), PointArrays._fields.index(Slacks._fields[-1]) + 1)
_SOLUTION = slice(PointArrays._fields.index(Solution._fields[0]), PointArrays._fields.index(Solution._fields[-1]) + 1)
assert PointArrays._fields[_SLACKS] == Slacks._fields and PointArrays._fields[_SOLUTION] == Solution._fields


def _setter(fields):
    """A function (obj, values) that sets the attributes ``fields`` of obj to values in one
    tuple assignment (generated from the bundle's field list: one statement, as fast as writing
    the fields out, which _Point does for every new point)."""
    namespace = {}
    exec(f"def set_fields(obj, values):\n    {', '.join('obj.' + f for f in fields)}, = values\n", namespace)
    return namespace["set_fields"]


_set_point_fields, _set_rhs_fields = _setter(PointArrays._fields), _setter(Residuals._fields)


class _PointForm:
    """The layout of the points of a prepared problem (a _Layout of PointArrays) and the mask of
    the dual fields (lam, nu, zl, zu)."""

    __slots__ = ("layout", "dual_mask", "kernels")

    def __init__(self, layout, kernels):
        self.layout, self.dual_mask = layout, layout.mask(DUAL_FIELDS)
        self.kernels = kernels   # the prepared QP's KernelSet (presolve._KERNELS)

    @classmethod
    def of(cls, layout, kernels):
        """The form of ``layout`` (a shared :meth:`_Layout.of`) with ``kernels``, made once per pair."""
        key = (id(layout), id(kernels))
        form = _FORMS.get(key)
        if form is None or form.layout is not layout or form.kernels is not kernels:
            if len(_FORMS) >= 64:
                _FORMS.clear()
            form = _FORMS[key] = cls(layout, kernels)
        return form


_FORMS: dict = {}   # _PointForm.of


class _Point:
    """An iterate, or a direction (the fields of bundles.PointArrays): views into one flat vector
    ``v``, as attributes and as the bundles the kernels take (plain tuples): ``arrays`` (all
    fields), ``slacks`` (the complementarity pairs, bundles.Slacks) and ``solution`` (the
    arrays a KKT back-end solves into, olado.linalg.backend.Solution)."""

    __slots__ = ("v", "arrays", "slacks", "solution", *PointArrays._fields, "_form", "max_step", "max_split", "_finite")

    def __init__(self, form, v):
        """``form``: the _PointForm of the prepared problem (not the problem itself: a point held
        by the problem -- its reused directions -- would make a reference cycle, and the
        problem's large arrays would then outlive the solve until Python's cyclic garbage
        collector runs, ~100 MB per solve at N = 12 000)."""
        self._form, self.v = form, v
        self.max_step = None    # cache of _StepContext.max_step for a direction
        self.max_split = None   # and of its (primal, dual) step lengths (set by _reduced_solve)
        self._finite = None     # whether every entry is finite (set by step_into)
        a = self.arrays = form.layout.views(v)
        _set_point_fields(self, a)
        self.slacks = a[_SLACKS]
        self.solution = a[_SOLUTION]

    def plus(self, alpha, d):
        return _Point(self._form, self._form.kernels.axpy(self.v, float(alpha), d.v))

    def plus_split(self, alpha, alpha_dual, d):
        """The point + alpha d on (X, U, tl, tu) and + alpha_dual d on (lam, nu, zl, zu)."""
        form = self._form
        return _Point(form, form.kernels.axpy_split(self.v, float(alpha), float(alpha_dual), d.v, form.dual_mask))

    def step_into(self, alpha, alpha_dual, d, out):
        """The point + alpha d on (X, U, tl, tu) and + alpha_dual d on (lam, nu, zl, zu) (the
        values of :meth:`plus`, :meth:`plus_split`), written into the point ``out`` of the same
        form (a reused one, not this point nor d: every field overwritten) in one pass that also
        finds whether it is finite. Returns ``out``."""
        form = self._form
        out.max_step = out.max_split = None
        out._finite = form.kernels.step_into(self.v, float(alpha), float(alpha_dual), d.v, form.dual_mask, out.v)
        return out

    def finite(self):
        if self._finite is None:
            self._finite = self._form.kernels.all_finite(self.v)
        return self._finite


class _Rhs:
    """Residuals of the Newton system's equations (see :meth:`_StepContext.solve`; the fields of
    bundles.Residuals): views into one flat vector ``buf``, as attributes and as the bundle
    ``arrays`` (a plain tuple), and ``kkt_rhs``, the KKT back-end's right-hand side of a solve for
    them (olado.linalg.backend.RHS)."""

    __slots__ = ("buf", "arrays", "kkt_rhs", *Residuals._fields, "_size", "_kernels")

    def __init__(self, P, buf):
        self.buf, self._size, self._kernels = buf, None, P.kernels
        self.arrays = P.rhs_layout.views(buf)
        _set_rhs_fields(self, self.arrays)
        # the right-hand side of the reduced system (25) for these residuals: the gradient and
        # stage-row terms go into the work arrays of P (step._newton_rhs), the rest are these rows
        self.kkt_rhs = tuple(RHS(q=P.work_q, r=P.work_r, c=self.dyn, x0=self.x0r, e=self.rE, eN=self.rEN, ci=P.work_ci))

    def size(self):
        """max-norm of all residuals."""
        if self._size is None:
            self._size = self._kernels.max_abs(self.buf)
        return self._size
