"""Points and residuals of the interior-point QP: an iterate or a direction is one flat vector
with views X, U, lam, nu (the primal and equality-multiplier parts s, p of paper 001 (16)-(17))
and tl, tu, zl, zu (the slacks w and multipliers lambda of the two sides of every box, (18)-(20));
a residual vector has the views of the equations of the Newton system (22).
"""

from __future__ import annotations

import collections

import numpy as np

from .kernels import _all_finite, _axpy, _axpy_split, _max_abs


#: the fields of a point (an iterate or a direction), and the bundle of its arrays the kernels
#: take: states X (N+1, n), controls U (N, m), dynamics and equality multipliers lam (N+1, n),
#: nu (N+1, n_nu), and the slacks tl, tu and multipliers zl, zu of the finite box sides (flat over
#: the boxes, 0 on infinite sides)
PointArrays = collections.namedtuple("PointArrays", "X U lam nu tl tu zl zu")
#: the multiplier fields of a point (the dual step length moves them)
DUAL_FIELDS = ("lam", "nu", "zl", "zu")
#: the equations of the Newton system (22) / the KKT conditions (16)-(20), and the bundle of
#: their arrays: stationarity rx (N+1, n), ru (N, m), dynamics dyn (N, n), initial state x0r (n,),
#: equality rows rE (N, ne), rEN (neN,) and the box sides rl, rup (flat); also the bundle of
#: offsets of the residual kernel (kkt_map._kkt_map)
Residuals = collections.namedtuple("Residuals", "rx ru dyn x0r rE rEN rl rup")


class _Layout:
    """Where the fields of a bundle (a namedtuple class) lie in one flat vector: ``spans``
    {name: (start, stop, shape)} in the bundle's field order, ``size`` the vector's length."""

    __slots__ = ("bundle", "spans", "size")

    def __init__(self, bundle, **shapes):
        if tuple(shapes) != bundle._fields:
            raise ValueError(f"layout of {bundle.__name__}: fields {tuple(shapes)}, expected {bundle._fields}")
        self.bundle, self.spans, o = bundle, {}, 0
        for name, shape in shapes.items():
            size = int(np.prod(shape))
            self.spans[name] = (o, o + size, shape)
            o += size
        self.size = o

    def views(self, v):
        """The bundle of the fields' views into the flat vector v (1-d fields as slices)."""
        return self.bundle(*(v[a:b] if len(shape) == 1 else v[a:b].reshape(shape) for a, b, shape in self.spans.values()))

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


class _PointForm:
    """The layout of the points of a prepared problem (a _Layout of PointArrays) and the mask of
    the dual fields (lam, nu, zl, zu)."""

    __slots__ = ("layout", "dual_mask")

    def __init__(self, layout):
        self.layout, self.dual_mask = layout, layout.mask(DUAL_FIELDS)


class _Point:
    """An iterate, or a direction (same fields, PointArrays): views into one flat vector ``v``,
    as attributes and as the bundle ``arrays`` the kernels take."""

    __slots__ = ("v", "arrays", "X", "U", "lam", "nu", "tl", "tu", "zl", "zu", "_form", "max_step", "max_split")

    def __init__(self, form, v):
        """``form``: the _PointForm of the prepared problem (not the problem itself: a point held
        by the problem -- its reused directions -- would make a reference cycle, and the
        problem's large arrays would then outlive the solve until Python's cyclic garbage
        collector runs, ~100 MB per solve at N = 12 000)."""
        self._form, self.v = form, v
        self.max_step = None    # cache of _StepContext.max_step for a direction
        self.max_split = None   # and of its (primal, dual) step lengths (set by _reduced_solve)
        a = self.arrays = form.layout.views(v)
        self.X, self.U, self.lam, self.nu = a.X, a.U, a.lam, a.nu
        self.tl, self.tu, self.zl, self.zu = a.tl, a.tu, a.zl, a.zu

    def plus(self, alpha, d):
        return _Point(self._form, _axpy(self.v, float(alpha), d.v))

    def plus_split(self, alpha, alpha_dual, d):
        """The point + alpha d on (X, U, tl, tu) and + alpha_dual d on (lam, nu, zl, zu)."""
        return _Point(self._form, _axpy_split(self.v, float(alpha), float(alpha_dual), d.v, self._form.dual_mask))

    def finite(self):
        return _all_finite(self.v)


class _Rhs:
    """Residuals of the Newton system's equations (see :meth:`_StepContext.solve`; Residuals):
    views into one flat vector ``buf``, as attributes and as the bundle ``arrays``."""

    __slots__ = ("buf", "arrays", "rx", "ru", "dyn", "x0r", "rE", "rEN", "rl", "rup", "_size")

    def __init__(self, P, buf):
        self.buf, self._size = buf, None
        a = self.arrays = P.rhs_layout.views(buf)
        self.rx, self.ru, self.dyn, self.x0r, self.rE, self.rEN = a.rx, a.ru, a.dyn, a.x0r, a.rE, a.rEN
        self.rl, self.rup = a.rl, a.rup

    def size(self):
        """max-norm of all residuals."""
        if self._size is None:
            self._size = _max_abs(self.buf)
        return self._size
