"""Points and residuals of the interior-point QP: an iterate or a direction is one flat vector
with views X, U, lam, nu (the primal and equality-multiplier parts s, p of paper 001 (16)-(17))
and tl, tu, zl, zu (the slacks w and multipliers lambda of the two sides of every box, (18)-(20));
a residual vector has the views of the equations of the Newton system (22).
"""

from __future__ import annotations

import numpy as np

from .kernels import _all_finite, _axpy, _axpy_split, _max_abs


def _layout(fields):
    """((name, start, stop, shape), ...), total size) of a flat vector holding the fields."""
    out, o = [], 0
    for name, shape in fields:
        size = int(np.prod(shape))
        out.append((name, o, o + size, shape))
        o += size
    return tuple(out), o


class _PointForm:
    """The layout of the points of a prepared problem: the (slice, shape) of each field and the
    mask of the dual fields (lam, nu, zl, zu)."""

    __slots__ = ("slices", "dual_mask")

    def __init__(self, slices, dual_mask):
        self.slices, self.dual_mask = slices, dual_mask


class _Point:
    """An iterate, or a direction (same fields): states X, controls U, dynamics and equality
    multipliers lam, nu, and the slacks tl, tu and multipliers zl, zu of the finite box sides
    (flat, 0 on infinite sides) -- views into one flat vector ``v``."""

    __slots__ = ("v", "X", "U", "lam", "nu", "tl", "tu", "zl", "zu", "_form", "max_step", "max_split")

    def __init__(self, form, v):
        """``form``: the _PointForm of the prepared problem (not the problem itself: a point held
        by the problem -- its reused directions -- would make a reference cycle, and the
        problem's large arrays would then outlive the solve until Python's cyclic garbage
        collector runs, ~100 MB per solve at N = 12 000)."""
        self._form, self.v = form, v
        self.max_step = None    # cache of _StepContext.max_step for a direction
        self.max_split = None   # and of its (primal, dual) step lengths (set by _reduced_solve)
        (sx, shx), (su, shu), (sl, shl), (sn, shn), stl, stu, szl, szu = form.slices
        self.X = v[sx].reshape(shx); self.U = v[su].reshape(shu)
        self.lam = v[sl].reshape(shl); self.nu = v[sn].reshape(shn)
        self.tl = v[stl]; self.tu = v[stu]; self.zl = v[szl]; self.zu = v[szu]

    def plus(self, alpha, d):
        return _Point(self._form, _axpy(self.v, float(alpha), d.v))

    def plus_split(self, alpha, alpha_dual, d):
        """The point + alpha d on (X, U, tl, tu) and + alpha_dual d on (lam, nu, zl, zu)."""
        return _Point(self._form, _axpy_split(self.v, float(alpha), float(alpha_dual), d.v, self._form.dual_mask))

    def finite(self):
        return _all_finite(self.v)

    # kernel argument helpers
    def tz(self):
        return self.tl, self.tu, self.zl, self.zu


class _Rhs:
    """Residuals of the Newton system's equations (see :meth:`_StepContext.solve`), views into
    one flat vector ``buf``: rx (N+1, n), ru (N, m), dyn (N, n), x0r (n,), rE (N, ne), rEN (neN,),
    rl, rup (flat over the boxes)."""

    __slots__ = ("buf", "rx", "ru", "dyn", "x0r", "rE", "rEN", "rl", "rup", "_size")

    def __init__(self, P, buf):
        self.buf, self._size = buf, None
        (sx, shx), (su, shu), (sd, shd), sx0, (se, she), seN, srl, sru = P.rhs_slices
        self.rx = buf[sx].reshape(shx); self.ru = buf[su].reshape(shu); self.dyn = buf[sd].reshape(shd)
        self.x0r = buf[sx0]; self.rE = buf[se].reshape(she); self.rEN = buf[seN]; self.rl = buf[srl]; self.rup = buf[sru]

    def size(self):
        """max-norm of all residuals."""
        if self._size is None:
            self._size = _max_abs(self.buf)
        return self._size
