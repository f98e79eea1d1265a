"""The compiled iteration (olado.solvers.ipm.compiled, iteration_kernels) takes the Python
path's iterates bit for bit: the same Result (x, u, multipliers, history, evaluation counts,
the problem's counters) with and without it, also where it hands iterations back (second-order
corrections, the watchdog, a time limit), and it applies only where its conditions hold."""

import numpy as np
import pytest

import olado.solvers.ipm.solver as ipm_solver
from olado.problems import PROBLEMS
from olado.problems.zambezi import zambezi_problem
from olado.solvers.ipm import iteration_kernels as IK
from olado.solvers.ipm.compiled import PlainPath, plain_path
from olado.solvers.ipm.solver import IPMSolver, Setup
from olado.interrupts import Limits


def _solve(problem_factory, plain, **options):
    p = problem_factory()
    solver = IPMSolver(**options)
    if plain:
        return solver.solve(p), dict(p.counters)
    original = ipm_solver.plain_path
    ipm_solver.plain_path = lambda setup: None
    try:
        return solver.solve(p), dict(p.counters)
    finally:
        ipm_solver.plain_path = original


def _same(a, b):
    (ra, ca), (rb, cb) = a, b
    assert ra.status == rb.status and ra.message == rb.message
    assert ra.iterations == rb.iterations and ra.objective == rb.objective
    assert np.array_equal(ra.x, rb.x) and np.array_equal(ra.u, rb.u)
    for k in ra.multipliers:
        assert np.array_equal(ra.multipliers[k], rb.multipliers[k]), k
    assert ra.history == rb.history
    assert ra.evaluations == rb.evaluations and ca == cb
    for k in ("factorizations", "restorations", "mu", "scaled_optimality_error"):
        assert ra.info[k] == rb.info[k], k
    assert ra.info["compiled_iterations"] == 0 < rb.info["compiled_iterations"] <= rb.iterations


@pytest.mark.parametrize("family,N", [("zambezi12", 24), ("zambezi", 48), ("zambezi12", 120)])
def test_compiled_iteration_takes_the_python_paths_iterates(family, N):
    def make():
        return zambezi_problem(family, N=N, start="balance")

    setup = Setup(IPMSolver().options, make(), Limits(), lambda entry: False)
    assert setup.plain is not None          # it applies here
    _same(_solve(make, False), _solve(make, True))


@pytest.mark.parametrize("start,options,codes", [
    ("balance", {"mu_init": 10.0, "max_soc": 1}, {IK.STEP}),
    ("sif", {}, {IK.INERTIA, IK.SOC}),
    ("sif", {"mu_init": 1e-4, "watchdog_shortened_iter_trigger": 1}, {IK.INERTIA, IK.WATCHDOG}),
    ("balance", {"tol": 1e-12, "acceptable_iter": 2}, {IK.SOC, IK.ACCEPTABLE_END}),
    ("balance", {"max_iter": 5}, {IK.MAX_ITERATIONS})])
def test_handed_back_iterations_and_ends_give_the_same_result(monkeypatch, start, options, codes):
    """Cases where the compiled iteration hands iterations back (the inertia correction, second-order
    corrections, the watchdog; ``codes`` says which occur) or the solve ends on another test."""
    def make():
        return zambezi_problem("zambezi" if start == "sif" else "zambezi12", N=24, start=start)

    seen = set()
    iterate = PlainPath.iterate

    def counted(self, st):
        done = iterate(self, st)
        if done is not None:
            seen.add(done[0])       # (the last code of the call's iterations)
        return done

    reference = _solve(make, False, **options)
    monkeypatch.setattr(PlainPath, "iterate", counted)
    _same(reference, _solve(make, True, **options))
    assert codes <= seen


def test_where_the_compiled_iteration_does_not_apply():
    limits = Limits()
    p = zambezi_problem("zambezi12", N=24, start="balance")
    assert plain_path(Setup(IPMSolver(mu_strategy="adaptive").options, p, limits, None)) is None
    assert Setup(IPMSolver().options, PROBLEMS["lq-box"](N=7), limits, None).plain is None   # no compiled evaluations
    big = zambezi_problem("zambezi", N=324, start="balance")        # above PLAIN_MAX
    assert Setup(IPMSolver().options, big, limits, None).plain is None


def test_callback_stop_and_log_lines_are_the_python_paths(capsys):
    """A callback that stops the solve and the verbose log see the same iterations."""
    def make():
        return zambezi_problem("zambezi12", N=24, start="balance")

    results, logs = [], []
    for plain in (False, True):
        seen = []
        result = _solve(make, plain, verbose=2, callback=lambda entry: seen.append(entry) or entry["iter"] >= 7)
        results.append(result)
        out = capsys.readouterr().out          # the iteration lines (the summary after them has timings)
        logs.append((out[:out.index("olado result")], seen))
    _same(*results)
    assert results[0][0].status.name == "USER_STOP" and results[0][0].iterations == 7
    assert logs[0] == logs[1] and logs[0][0].count("\n") >= 7


def test_interrupt_during_compiled_iterations_keeps_the_iterate_reached():
    """A stop from outside between compiled iterations (here the time limit, checked at every
    iteration) ends with the iterate reached, as the Python path's: the state goes back first."""
    def make():
        return zambezi_problem("zambezi12", N=24, start="balance")

    calls = []

    def slow(entry):
        calls.append(entry["iter"])
        if entry["iter"] == 4:
            import time
            time.sleep(0.3)
        return False

    result, _ = _solve(make, True, callback=slow, max_time=0.25)
    assert result.status.name == "MAX_TIME" and result.iterations == 4
    reference, _ = _solve(make, True, max_iter=4)
    assert np.array_equal(result.x, reference.x) and result.objective == reference.objective


def test_the_kernels_called_at_addresses_are_the_python_paths_versions(monkeypatch):
    """The kernels plain_iteration calls at their addresses (iteration_kernels.KERNELS) are
    declared with the argument types the Python path calls them with: their compiled versions are
    shared, not compiled twice (the Riccati kernels' types follow the arguments themselves)."""
    import numba
    from olado.solvers.ipm import kernels as K

    seen = {}
    for name, dispatcher, sig in IK.KERNELS:
        if not callable(sig):
            def spy(*args, _d=dispatcher, _n=name):
                seen.setdefault(_n, set()).add(tuple(numba.typeof(a) for a in args))
                return _d(*args)
            monkeypatch.setattr(K, name, spy)
    _solve(lambda: zambezi_problem("zambezi12", N=24, start="balance"), False)
    for name, dispatcher, sig in IK.KERNELS:
        if name == "barrier_logs":      # the Python path calls it inside point_terms
            assert tuple(sig.args) in dispatcher.signatures
        elif not callable(sig):
            assert tuple(sig.args) in seen[name], name


def test_a_kernel_of_other_types_is_refused():
    """kernel_addresses refuses a kernel whose return type is not the declared one (the compiled
    iteration would read it wrongly), and a call at an address with other argument types than
    the declared ones does not compile."""
    import numba
    from numba.core import types

    setup = Setup(IPMSolver().options, zambezi_problem("zambezi12", N=24, start="balance"), Limits(), None)
    plain = setup.plain
    assert np.array_equal(IK.kernel_addresses(plain.tags, plain.ipt, plain.fac), plain.addresses[4:])
    kernels = list(IK.KERNELS)
    i = [name for name, _, _ in kernels].index("shifted_diagonals")
    name, dispatcher, sig = kernels[i]
    kernels[i] = (name, dispatcher, types.float64(*sig.args))
    original = IK.KERNELS
    IK.KERNELS = tuple(kernels)
    try:
        with pytest.raises(TypeError, match="shifted_diagonals returns none, not float64"):
            IK.kernel_addresses(plain.tags, plain.ipt, plain.fac)
    finally:
        IK.KERNELS = original

    @numba.njit
    def call(address, a):
        return IK._dot(address, a, a)

    with pytest.raises(numba.core.errors.TypingError, match="its compiled version takes"):
        call(plain.addresses[IK.DOT], np.zeros(3, dtype=np.float32))
