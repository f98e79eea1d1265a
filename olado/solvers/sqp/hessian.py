"""Approximations of the block-diagonal Lagrangian Hessian (12) for the SQP method (paper 001
sec. 4.2.1): every option keeps the stage block structure, one (n+m) block per stage k < N and an
n block for x^N, so the QP subproblem stays an LQ-DOCP.

* :class:`ExactHessian` -- analytic (or finite-difference) second derivatives, made positive
  definite by the Gerschgorin modification (13) or by a Levenberg shift of the block.
* :class:`BlockBFGS` -- BFGS on each diagonal block separately, with Powell's damping
  (Powell 1978): y is replaced by theta*y + (1-theta)*B s when s.y < 0.2 s.B s; a block whose
  condition number exceeds ``max_condition`` is restarted as a multiple of I.
* :class:`BlockSR1` -- symmetric rank-one update of each block (skipped when the denominator is
  tiny, Nocedal & Wright 1999 sec. 6.2), with a positive-definiteness safeguard: eigenvalues
  below ``min_eig`` are raised (Tenny et al. 2002 use SR1 with such a safeguard).
* :class:`PowellBFGS` -- Powell's damped BFGS on the *whole* matrix followed by the gangster
  operator, which keeps only the block-diagonal pattern: the global scalars s.B s and s.y of the
  full update are used, and only the block-diagonal part of the rank-two correction is kept.
  Positive definiteness is then restored by the same eigenvalue safeguard.

Blocks are stacked arrays: ``blocks`` (N, n+m, n+m) and ``final`` (n, n).
"""

from __future__ import annotations

import math

import numpy as np


def _psd_floor(blocks, min_eig):
    """Raise the eigenvalues of every block to at least ``min_eig`` (vectorized eigh)."""
    w, V = np.linalg.eigh(0.5 * (blocks + np.swapaxes(blocks, -1, -2)))
    if np.all(w >= min_eig):
        return blocks
    w = np.maximum(w, min_eig)
    return np.einsum("...ij,...j,...kj->...ik", V, w, V)


def gerschgorin(blocks, eps):
    """Modification (13): h_ii := max(eps + sum_{j != i} |h_ij|, h_ii), block by block."""
    off = np.sum(np.abs(blocks), axis=-1) - np.abs(np.diagonal(blocks, axis1=-2, axis2=-1))
    out = blocks.copy()
    d = np.diagonal(out, axis1=-2, axis2=-1)
    idx = np.arange(blocks.shape[-1])
    out[..., idx, idx] = np.maximum(eps + off, d)
    return out


def levenberg(blocks, min_eig):
    """Shift each block by the smallest delta*I that makes its eigenvalues >= min_eig."""
    w = np.linalg.eigvalsh(0.5 * (blocks + np.swapaxes(blocks, -1, -2)))
    shift = np.maximum(min_eig - w[..., 0], 0.0)
    idx = np.arange(blocks.shape[-1])
    out = blocks.copy()
    out[..., idx, idx] += shift[..., None]
    return out


class HessianApproximation:
    """Interface: ``initial(N, n, m)``, ``blocks(...)``, ``update(s_blocks, sN, y_blocks, yN)``."""

    needs_exact = False
    name = "hessian"

    def __init__(self, initial_scale=1.0, min_eig=1e-8):
        # initial_scale 0 means "automatic": the identity is rescaled at the first update by
        # y.y / s.y block by block (Shanno & Phua 1978; Nocedal & Wright 1999 eq. (6.20))
        self.initial_scale = float(initial_scale)
        self.auto_scale = self.initial_scale == 0.0
        self.min_eig = float(min_eig)
        self.B = None
        self.BN = None
        self.updates = 0
        self.skipped = 0

    def initial(self, N, n, m):
        scale = 1.0 if self.auto_scale else self.initial_scale
        self.B = np.tile(scale * np.eye(n + m), (N, 1, 1))
        self.BN = scale * np.eye(n)
        self._first = self.auto_scale

    def _rescale_first(self, s, sN, y, yN):
        """Automatic initial scaling: B0 = (y.y / s.y) I per block where s.y > 0."""
        if not self._first:
            return
        self._first = False

        def gamma(s_, y_):
            sy = np.einsum("...i,...i->...", s_, y_)
            yy = np.einsum("...i,...i->...", y_, y_)
            return np.where(sy > 1e-300, yy / np.where(sy > 1e-300, sy, 1.0), 1.0)

        g = gamma(s, y)
        self.B = self.B * g[:, None, None]
        self.BN = self.BN * float(gamma(sN, yN))

    def current(self):
        return self.B, self.BN

    def update(self, s, sN, y, yN):  # pragma: no cover - abstract
        raise NotImplementedError


class BlockBFGS(HessianApproximation):
    """Partitioned BFGS with Powell's damping, one update per diagonal block.

    Blocks whose condition number exceeds ``max_condition`` after an update are reset to the
    geometric mean of their eigenvalues times I (a restart of that block's approximation). In
    the flat directions of a degenerate optimum the damping lets a block's curvature fall
    geometrically (s.y ~ 0), and a later step with a component there adds r r^T / s.r with a
    tiny s.r: the block becomes ill-conditioned and the steps tiny (measured on zambezi12:
    docs/structure-exploiting-sqp.md, Known limitations)."""

    name = "bfgs"

    def __init__(self, damping=0.2, max_condition=1e8, **kw):
        super().__init__(**kw)
        self.damping = float(damping)
        self.max_condition = float(max_condition)
        self.resets = 0

    def _restart_ill_conditioned(self, B):
        """Reset the blocks of B (..., d, d) with condition number > max_condition."""
        if not math.isfinite(self.max_condition):
            return B
        w = np.linalg.eigvalsh(0.5 * (B + np.swapaxes(B, -1, -2)))
        bad = w[..., -1] > self.max_condition * np.maximum(w[..., 0], 1e-300)
        if not np.any(bad):
            return B
        g = np.exp(np.mean(np.log(np.maximum(w, 1e-300)), axis=-1))
        self.resets += int(np.sum(bad))
        return np.where(bad[..., None, None], g[..., None, None] * np.eye(B.shape[-1]), B)

    def _bfgs(self, B, s, y):
        Bs = np.einsum("...ij,...j->...i", B, s)
        sBs = np.einsum("...i,...i->...", s, Bs)
        sy = np.einsum("...i,...i->...", s, y)
        ok = sBs > 1e-16 * np.maximum(1.0, np.einsum("...i,...i->...", s, s))
        theta = np.where(sy >= self.damping * sBs, 1.0, (1 - self.damping) * sBs / np.maximum(sBs - sy, 1e-300))
        r = theta[..., None] * y + (1 - theta)[..., None] * Bs
        sr = np.einsum("...i,...i->...", s, r)
        ok &= sr > 0
        safe = np.where(ok, 1.0, 0.0)
        upd = (-np.einsum("...i,...j->...ij", Bs, Bs) / np.where(ok, sBs, 1.0)[..., None, None]
               + np.einsum("...i,...j->...ij", r, r) / np.where(ok, sr, 1.0)[..., None, None])
        self.updates += int(np.sum(ok)); self.skipped += int(np.sum(~ok))
        return self._restart_ill_conditioned(B + safe[..., None, None] * upd)

    def update(self, s, sN, y, yN):
        self._rescale_first(s, sN, y, yN)
        self.B = self._bfgs(self.B, s, y)
        self.BN = self._bfgs(self.BN, sN, yN)


class BlockSR1(HessianApproximation):
    """Partitioned SR1 with skipping and an eigenvalue floor for positive definiteness."""

    name = "sr1"

    def __init__(self, skip=1e-8, **kw):
        super().__init__(**kw)
        self.skip = float(skip)

    def _sr1(self, B, s, y):
        v = y - np.einsum("...ij,...j->...i", B, s)
        den = np.einsum("...i,...i->...", s, v)
        ok = np.abs(den) > self.skip * np.linalg.norm(s, axis=-1) * np.linalg.norm(v, axis=-1)
        ok &= np.linalg.norm(s, axis=-1) > 0
        upd = np.einsum("...i,...j->...ij", v, v) / np.where(ok, den, 1.0)[..., None, None]
        self.updates += int(np.sum(ok)); self.skipped += int(np.sum(~ok))
        return _psd_floor(B + np.where(ok, 1.0, 0.0)[..., None, None] * upd, self.min_eig)

    def update(self, s, sN, y, yN):
        self._rescale_first(s, sN, y, yN)
        self.B = self._sr1(self.B, s, y)
        self.BN = self._sr1(self.BN, sN, yN)


class PowellBFGS(HessianApproximation):
    """Powell's damped BFGS on the whole Hessian, projected by the gangster operator onto the
    block-diagonal pattern (paper 001 sec. 4.2.1, last paragraph)."""

    name = "powell-bfgs"

    def __init__(self, damping=0.2, **kw):
        super().__init__(**kw)
        self.damping = float(damping)

    def update(self, s, sN, y, yN):
        self._rescale_first(s, sN, y, yN)
        Bs = np.einsum("kij,kj->ki", self.B, s)
        BsN = self.BN @ sN
        sBs = float(np.sum(s * Bs) + sN @ BsN)
        sy = float(np.sum(s * y) + sN @ yN)
        if sBs <= 1e-16:
            self.skipped += 1
            return
        theta = 1.0 if sy >= self.damping * sBs else (1 - self.damping) * sBs / (sBs - sy)
        r, rN = theta * y + (1 - theta) * Bs, theta * yN + (1 - theta) * BsN
        sr = float(np.sum(s * r) + sN @ rN)
        if sr <= 0:
            self.skipped += 1
            return
        # gangster operator: keep only the block-diagonal part of the rank-two correction
        self.B = self.B - np.einsum("ki,kj->kij", Bs, Bs) / sBs + np.einsum("ki,kj->kij", r, r) / sr
        self.BN = self.BN - np.outer(BsN, BsN) / sBs + np.outer(rN, rN) / sr
        self.B = _psd_floor(self.B, self.min_eig)
        self.BN = _psd_floor(self.BN, self.min_eig)
        self.updates += 1


class ExactHessian(HessianApproximation):
    """The problem's second derivatives, convexified block by block ("gerschgorin" (13) or
    "levenberg")."""

    needs_exact = True
    name = "exact"

    def __init__(self, convexify="levenberg", **kw):
        super().__init__(**kw)
        if convexify not in ("levenberg", "gerschgorin", "inertia", "none"):
            raise ValueError(f"convexify must be levenberg, gerschgorin, inertia or none, got {convexify!r}")
        self.convexify = convexify

    def set_exact(self, blocks, final):
        if self.convexify == "levenberg":
            blocks, final = levenberg(blocks, self.min_eig), levenberg(final, self.min_eig)
        elif self.convexify == "gerschgorin":
            blocks, final = gerschgorin(blocks, self.min_eig), gerschgorin(final, self.min_eig)
        self.B, self.BN = blocks, final

    def update(self, s, sN, y, yN):
        pass


def make_hessian(name, convexify="levenberg", initial_scale=1.0, min_eig=1e-8, max_condition=1e8):
    """Hessian option name -> approximation object."""
    if name == "bfgs":
        return BlockBFGS(initial_scale=initial_scale, min_eig=min_eig, max_condition=max_condition)
    if name == "sr1":
        return BlockSR1(initial_scale=initial_scale, min_eig=min_eig)
    if name == "powell-bfgs":
        return PowellBFGS(initial_scale=initial_scale, min_eig=min_eig)
    if name == "exact":
        return ExactHessian(convexify=convexify, initial_scale=initial_scale, min_eig=min_eig)
    raise ValueError(f"unknown Hessian option {name!r} (allowed: bfgs, sr1, powell-bfgs, exact)")
