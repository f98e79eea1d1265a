"""The certificate's compiled passes (olado.solvers.certificate: _bound_choice_kernel and
_spot_figures) against the numpy formulas they replace, bit for bit, on random data with NaN,
inf, fixed variables, zeros and ties; and a certificate of a solve that is the same before and
after (its figures come from these passes)."""

import numpy as np
import pytest

from olado.solvers import certificate as C


def _bound_choice_numpy(r, y, lo, hi, w):
    """The numpy formulas of step 2 (module docstring) as they were written before the kernel."""
    with np.errstate(invalid="ignore", over="ignore"):
        slack = np.where(r > 0, y - lo, hi - y)
        slack = np.maximum(slack, 0.0)
        bounded = np.isfinite(slack)
        a = np.abs(r)
        z = np.where(bounded, a * w / (w + np.where(bounded, slack, 0.0)), 0.0)
        stat = a - z
        comp = np.where(bounded, z * np.where(bounded, slack, 0.0), 0.0)
    fixed = lo == hi
    return np.where(fixed, 0.0, stat), np.where(fixed, 0.0, comp)


def _spot_numpy(vals, an, size, h):
    """The numpy formulas of the spot check's figures as they were written before the kernel."""
    v1, m1, v2, m2 = (vals[:, i] for i in range(4))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        d_h = (v1 - m1) / (2 * h)
        d_2h = (v2 - m2) / (4 * h)
        d5 = (4 * d_h - d_2h) / 3
        rounding = C._EPS * (np.abs(v1) + np.abs(m1) + np.abs(v2) + np.abs(m2)) / h
        allowed = C.CHECK_RTOL * np.maximum(size, np.abs(d5)) + 10 * (np.abs(d_h - d_2h) + rounding) + 1e-300
        err = np.abs(d5 - an)
        rel = err / np.maximum(np.maximum(size, np.abs(d5)), 1e-300)
        worst = max(0.0, float(np.where(err > 10 * rounding, rel, 0.0).max()))
        ratio = (err / allowed).ravel()
    j = int(np.argmax(ratio))
    return worst, j, ratio[j], d5, rel


def _spiked(rng, shape, rate=0.08):
    a = rng.standard_normal(shape) * 10.0 ** rng.integers(-3, 4, shape)
    for value in (np.nan, np.inf, -np.inf, 0.0, -0.0):
        a[rng.random(shape) < rate] = value
    return a


def _same_bits(a, b):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    np.testing.assert_array_equal(a.view(np.int64), b.view(np.int64))


@pytest.mark.parametrize("seed", range(6))
def test_bound_choice_kernel_equals_the_numpy_formulas(seed):
    rng = np.random.default_rng(seed)
    shape = (13, 5)
    y = _spiked(rng, shape, 0.02)
    lo = y - np.abs(rng.standard_normal(shape))
    hi = y + np.abs(rng.standard_normal(shape))
    lo[rng.random(shape) < 0.2] = -np.inf
    hi[rng.random(shape) < 0.2] = np.inf
    fixed = rng.random(shape) < 0.1
    lo[fixed] = hi[fixed] = y[fixed]
    outside = rng.random(shape) < 0.1
    lo[outside] = y[outside] + 1.0           # a variable below its lower bound: negative slack
    hi[outside] = np.maximum(hi[outside], lo[outside])
    r = _spiked(rng, shape)
    w = np.maximum(1.0, np.abs(np.nan_to_num(y)))
    with np.errstate(invalid="ignore"):
        got = C._bound_choice(r, y, lo, hi, w)
    ref = _bound_choice_numpy(r, y, lo, hi, w)
    for a, b in zip(got, ref):
        _same_bits(a, b)


@pytest.mark.parametrize("seed", range(8))
def test_spot_figures_kernel_equals_the_numpy_formulas(seed):
    rng = np.random.default_rng(100 + seed)
    D, L, h = 2, 37, C.CHECK_STEP
    base = rng.standard_normal((D, 1, L))
    slope = rng.standard_normal((D, 1, L))
    steps = np.array(C._SHIFTS, dtype=float)[None, :, None] * h
    vals = base + slope * steps + rng.standard_normal((D, 4, L)) * 10.0 ** rng.integers(-16, -4)
    an = slope[:, 0] + rng.standard_normal((D, L)) * 10.0 ** rng.integers(-12, 0)
    size = np.abs(an) * rng.uniform(1.0, 3.0, (D, L))
    if seed % 2:                              # NaN and inf entries, ties
        vals[rng.random(vals.shape) < 0.03] = np.nan
        an[rng.random(an.shape) < 0.03] = np.inf
        size[0, :3] = 0.0
        an[1, 5:8] = an[1, 4]
    if seed == 2:                             # an exact tie of the largest ratio
        vals[1] = vals[0]
        an[1], size[1] = an[0], size[0]
    d5, rel = np.empty((D, L)), np.empty((D, L))
    with np.errstate(invalid="ignore"):
        worst, j, ratio_j = C._spot_figures(vals, an, size, h, d5, rel)
    ref = _spot_numpy(vals, an, size, h)
    _same_bits([worst, ratio_j], [ref[0], ref[2]])
    assert j == ref[1]
    _same_bits(d5, ref[3])
    _same_bits(rel, ref[4])
