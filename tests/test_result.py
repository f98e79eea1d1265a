"""olado.result: summary text, JSON + npz round trip, atomic writes, plots."""

import json
import math
import os

import numpy as np
import pytest

import olado.result as result_module
from olado.errors import OladoError
from olado.result import Result, Status, atomic_write_bytes

REQUIRED_KEYS = ("problem", "N", "solver", "status", "success", "objective",
                 "max_constraint_violation", "iterations", "qp_iterations", "time_s", "x", "u")


def make_result(seed=0, **changes):
    rng = np.random.default_rng(seed)
    N, n, m = 5, 3, 2
    fields = dict(
        status=Status.ACCEPTABLE,
        message="stopped at an acceptable point",
        objective=-0.1234567890123456789,
        x=rng.standard_normal((N + 1, n)) * 1e3,
        u=rng.standard_normal((N, m)) / 3.0,
        multipliers={"dynamics": rng.standard_normal((N, n)), "final_constraints": np.array([0.5])},
        max_constraint_violation=1.5e-11,
        kkt_residual=3.0e-9,
        iterations=17,
        qp_iterations=42,
        evaluations={"dynamics": 18, "jacobian": 17},
        time_s=0.25,
        history=[{"iteration": 0, "objective": 1.0, "violation": math.inf},
                 {"iteration": 1, "objective": 0.5, "violation": 1e-3}],
        problem="toy",
        N=N,
        solver="ipopt",
        options={"tol": 1e-8, "max_time": math.inf, "ipopt_options": {"mu_strategy": "adaptive"}},
        info={"callback_time_s": 0.01},
    )
    fields.update(changes)
    return Result(**fields)


def tmp_files(folder):
    return [p.name for p in folder.iterdir() if p.name.endswith(".tmp")]


# ---------------------------------------------------------------------------- save / load
def test_round_trip_is_exact(tmp_path):
    r = make_result()
    path = r.save(tmp_path / "res.json")
    assert path == tmp_path / "res.json" and (tmp_path / "res.npz").exists()
    back = Result.load(path)
    for name in ("x", "u"):
        a, b = getattr(r, name), getattr(back, name)
        assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)
    assert set(back.multipliers) == set(r.multipliers)
    for k in r.multipliers:
        assert np.array_equal(back.multipliers[k], r.multipliers[k])
    assert back.status is Status.ACCEPTABLE and back.success
    assert back.objective == r.objective  # bit-exact through JSON
    for name in ("message", "max_constraint_violation", "kkt_residual", "iterations", "qp_iterations",
                 "evaluations", "time_s", "problem", "N", "solver"):
        assert getattr(back, name) == getattr(r, name), name
    assert back.info == r.info
    assert back.history[1] == r.history[1]
    assert back.options["ipopt_options"] == {"mu_strategy": "adaptive"}


def test_json_is_plain_and_complete(tmp_path):
    r = make_result(objective=math.nan, kkt_residual=None)
    path = r.save(tmp_path / "res.json")
    data = json.loads(path.read_text())
    for key in REQUIRED_KEYS:
        assert key in data, key
    assert data["status"] == "acceptable" and data["success"] is True
    assert data["N"] == 5 and data["iterations"] == 17 and data["qp_iterations"] == 42
    assert np.array_equal(np.array(data["x"]), r.x) and np.array_equal(np.array(data["u"]), r.u)
    assert data["objective"] == "nan" and data["kkt_residual"] is None
    assert data["options"]["max_time"] == "inf"  # non-finite floats as strings: strict JSON
    back = Result.load(path)
    assert math.isnan(back.objective) and back.kkt_residual is None


def test_load_without_npz_uses_json_arrays(tmp_path):
    r = make_result()
    path = r.save(tmp_path / "res.json")
    (tmp_path / "res.npz").unlink()
    back = Result.load(path)
    assert np.array_equal(back.x, r.x) and np.array_equal(back.u, r.u)  # repr floats round-trip


def test_suffix_is_json(tmp_path):
    path = make_result().save(tmp_path / "res")
    assert path.suffix == ".json" and path.exists()
    assert Result.load(tmp_path / "res").N == 5


def test_load_rejects_bad_files(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(OladoError) as exc:
        Result.load(bad)
    assert "bad.json" in str(exc.value)
    with pytest.raises(FileNotFoundError):   # a ResultFileError that is a FileNotFoundError too
        Result.load(tmp_path / "missing.json")


# ---------------------------------------------------------------------------- atomic writes
@pytest.mark.parametrize("where", ["write", "fsync", "replace"])
def test_failed_save_keeps_old_file_and_leaves_no_temp(tmp_path, monkeypatch, where):
    old = make_result(seed=1)
    path = old.save(tmp_path / "res.json")
    before_json, before_npz = path.read_bytes(), path.with_suffix(".npz").read_bytes()

    def boom(*args, **kwargs):
        raise OSError("disk full (simulated)")

    if where == "write":
        real_fdopen = os.fdopen

        class Half:
            def __init__(self, fh):
                self.fh = fh

            def __enter__(self):
                return self

            def __exit__(self, *exc):
                self.fh.close()
                return False

            def write(self, data):
                self.fh.write(data[: len(data) // 2])
                raise OSError("disk full (simulated)")

        monkeypatch.setattr(result_module.os, "fdopen", lambda fd, mode: Half(real_fdopen(fd, mode)))
    elif where == "fsync":
        monkeypatch.setattr(result_module.os, "fsync", boom)
    else:
        monkeypatch.setattr(result_module.os, "replace", boom)

    new = make_result(seed=2, objective=99.0)
    with pytest.raises(OSError, match="simulated"):
        new.save(path)
    monkeypatch.undo()
    assert path.read_bytes() == before_json
    assert path.with_suffix(".npz").read_bytes() == before_npz
    assert tmp_files(tmp_path) == []
    assert Result.load(path).objective == old.objective


def test_failure_between_npz_and_json_is_not_mixed(tmp_path, monkeypatch):
    """A crash after the npz was replaced and before the JSON was: the new npz is not paired
    with the old JSON (their save ids differ), and no temporary file is left."""
    old = make_result(seed=1)
    path = old.save(tmp_path / "res.json")
    npz_before = path.with_suffix(".npz").read_bytes()
    real = os.replace

    def fail_on_json(src, dst):
        if str(dst).endswith(".json"):
            raise OSError("crash between the two writes (simulated)")
        real(src, dst)

    monkeypatch.setattr(result_module.os, "replace", fail_on_json)
    with pytest.raises(OSError):
        make_result(seed=2).save(path)
    monkeypatch.undo()
    assert path.with_suffix(".npz").read_bytes() != npz_before   # the new arrays did land
    assert tmp_files(tmp_path) == []
    back = Result.load(path)
    assert np.array_equal(back.x, old.x) and back.objective == old.objective


@pytest.mark.parametrize("mode", [0o600, 0o640, 0o644])
def test_save_keeps_the_replaced_files_permissions(tmp_path, mode):
    path = make_result(seed=1).save(tmp_path / "res.json")
    for f in (path, path.with_suffix(".npz")):
        os.chmod(f, mode)
    make_result(seed=2).save(path)
    for f in (path, path.with_suffix(".npz")):
        assert os.stat(f).st_mode & 0o777 == mode, f.name
    assert Result.load(path).x.tolist() == make_result(seed=2).x.tolist()


def test_new_npz_beside_a_private_json_is_private_too(tmp_path):
    path = make_result(seed=1).save(tmp_path / "res.json")
    os.chmod(path, 0o600)
    path.with_suffix(".npz").unlink()
    make_result(seed=2).save(path)
    assert os.stat(path.with_suffix(".npz")).st_mode & 0o777 == 0o600


def test_save_through_a_symlink_replaces_the_target(tmp_path):
    real_dir = tmp_path / "real"
    real_dir.mkdir()
    target = make_result(seed=1).save(real_dir / "res.json")
    link = tmp_path / "link.json"
    link.symlink_to(target)
    make_result(seed=2, objective=7.0).save(link)
    assert link.is_symlink() and Result.load(target).objective == 7.0
    assert not (tmp_path / "link.npz").exists()


def test_atomic_write_bytes_replaces(tmp_path):
    target = tmp_path / "sub" / "f.bin"
    atomic_write_bytes(target, b"one")
    atomic_write_bytes(target, b"two")
    assert target.read_bytes() == b"two" and tmp_files(target.parent) == []


def test_unserialisable_values_do_not_break_save(tmp_path):
    r = make_result(options={"callback": print, "flag": np.bool_(True), "count": np.int64(3)})
    back = Result.load(r.save(tmp_path / "res.json"))
    assert back.options["flag"] is True and back.options["count"] == 3
    assert isinstance(back.options["callback"], str)


# ---------------------------------------------------------------------------- text
def test_summary_contents():
    text = make_result().summary()
    for part in ("toy", "N=5", "n=3", "m=2", "ipopt", "acceptable", "stopped at an acceptable point",
                 "-0.123456789012", "1.500e-11", "KKT residual", "3.000e-09", "iterations   : 17",
                 "QP iterations 42", "dynamics 18", "time", "0.250 s"):
        assert part in text, part
    plain = make_result(message="", kkt_residual=None, qp_iterations=0, evaluations={}).summary()
    assert Status.ACCEPTABLE.sentence in plain
    assert "KKT residual" not in plain and "QP iterations" not in plain


def test_status_sentences_and_success():
    assert {s for s in Status if s.success} == {Status.SUCCESS, Status.ACCEPTABLE}
    for s in Status:
        assert s.sentence and s.sentence.endswith(".")
        assert Status(s.value) is s


# ---------------------------------------------------------------------------- plot
def test_plot_writes_png(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = tmp_path / "plot.png"
    fig = make_result().plot(path)
    plt.close(fig)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert tmp_files(tmp_path) == []
