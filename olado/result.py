"""The one result type every olado solver returns (docs/architecture.md, "The solver side").

A :class:`Result` carries the status (an enum with a human sentence), the state and control
trajectories, multipliers, objective, constraint violation, KKT residual, counts, timings and the
per-iteration history; olado's certificate of a success (:class:`Certificate`) and the diagnosis of
an infeasible result (:class:`Infeasibility`: the constraints that stay violated, array, stage and
component). It prints a summary, plots itself and saves/loads as JSON + npz, written
atomically (a crash mid-save never leaves a half-written file).
"""

from __future__ import annotations

import dataclasses
import enum
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np

from .errors import ResultFileError, ResultFileNotFoundError


class Status(enum.Enum):
    """Why a solver stopped. ``.sentence`` is the human explanation."""

    SUCCESS = "success"
    ACCEPTABLE = "acceptable"
    MAX_ITERATIONS = "max_iterations"
    MAX_TIME = "max_time"
    INFEASIBLE = "infeasible"
    UNBOUNDED = "unbounded"
    NUMERICAL_ERROR = "numerical_error"
    USER_STOP = "user_stop"
    INTERRUPTED = "interrupted"
    INVALID_PROBLEM = "invalid_problem"
    FAILED = "failed"
    UNCERTIFIED = "uncertified"

    @property
    def sentence(self) -> str:
        return _SENTENCES[self]

    @property
    def success(self) -> bool:
        return self in (Status.SUCCESS, Status.ACCEPTABLE)


_SENTENCES = {
    Status.SUCCESS: "The solver converged: the optimality and feasibility tolerances are met.",
    Status.ACCEPTABLE: "The solver stopped at a point that meets the looser 'acceptable' tolerances only.",
    Status.MAX_ITERATIONS: "The iteration limit was reached before the tolerances were met.",
    Status.MAX_TIME: "The time limit was reached before the tolerances were met.",
    Status.INFEASIBLE: "The problem appears to be (locally) infeasible: the constraint violation could not be reduced to zero.",
    Status.UNBOUNDED: "The problem appears to be unbounded below.",
    Status.NUMERICAL_ERROR: "The solver stopped on a numerical difficulty (failed line search, singular system or non-finite values).",
    Status.USER_STOP: "A user callback asked the solver to stop.",
    Status.INTERRUPTED: ("The solve was interrupted (Ctrl-C / SIGINT, SIGTERM or a KeyboardInterrupt) and stopped at "
                         "the next safe point; the result holds the last accepted iterate."),
    Status.INVALID_PROBLEM: "The problem could not be evaluated at the points the solver needed.",
    Status.FAILED: "The solver failed for another reason; see the message.",
    Status.UNCERTIFIED: ("The solver reported convergence, but olado's independent check of the first-order "
                         "optimality conditions does not hold at the returned point; the message names the "
                         "condition that fails."),
}


def _jsonable(value):
    """Convert numpy scalars/arrays (recursively) to plain JSON types; non-finite floats to str."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return v if math.isfinite(v) else str(v)
    if isinstance(value, (np.bool_,)):
        return bool(value)
    if isinstance(value, enum.Enum):
        return value.value
    if value is None or isinstance(value, (str, int, bool)):
        return value
    return repr(value)


def _file_modes(paths) -> list[int]:
    """Permission bits for files written at ``paths``: those of the file each replaces (a user's
    private 0600 result stays private); for a new file those of another of ``paths`` that exists
    (a new npz beside a private JSON), else an ordinary new file's (0666 less the umask)."""
    modes = []
    for path in paths:
        try:
            modes.append(os.stat(path).st_mode & 0o7777)
        except OSError:
            modes.append(None)
    known = [m for m in modes if m is not None]
    if known:
        default = known[0]
    else:
        umask = os.umask(0)
        os.umask(umask)
        default = 0o666 & ~umask
    return [default if m is None else m for m in modes]


def _real_path(path) -> Path:
    """``path`` with symbolic links resolved: a save replaces the file a link points to, not the link."""
    return Path(os.path.realpath(path))


def _write_temporary(path: Path, data: bytes, mode: int) -> str:
    """Write ``data`` to a new temporary file beside ``path`` (flushed to disk, mode ``mode``);
    return its name. Nothing is left behind on failure."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, mode)   # mkstemp creates 0600
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
    except BaseException:
        _remove_quietly(tmp)
        raise
    return tmp


def _remove_quietly(name) -> None:
    try:
        os.unlink(name)
    except OSError:
        pass


def atomic_write_files(items) -> None:
    """Write several files all-or-nothing as far as a file system allows: every ``(path, data)``
    first goes to a temporary file beside its target (flushed to disk), and only when all are
    written are they moved over their targets with ``os.replace``, one after the other. A failure
    while writing leaves every target as it was and no temporary file; a crash between two
    replaces leaves complete files only (a result's JSON and npz carry a shared ``save_id`` for
    that case, see :meth:`Result.save`). A replaced file keeps its permission bits."""
    items = [(_real_path(path), data) for path, data in items]
    modes = _file_modes([path for path, _ in items])
    staged = []
    try:
        for (path, data), mode in zip(items, modes):
            staged.append((_write_temporary(path, data, mode), path))
        while staged:
            tmp, path = staged[0]
            os.replace(tmp, path)
            staged.pop(0)
    except BaseException:
        for tmp, _ in staged:
            _remove_quietly(tmp)
        raise


def atomic_write_bytes(path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder and os.replace
    (:func:`atomic_write_files` with one file)."""
    atomic_write_files([(path, data)])


@dataclasses.dataclass
class Certificate:
    """olado's independent check of the first-order optimality conditions at a point a solver
    reported as optimal (computed by :mod:`olado.solvers.certificate`; docs/certificate.md).

    ``level`` is ``"success"`` (every figure within its tolerance), ``"acceptable"`` (within the
    acceptable tolerances only) or ``"failed"``; ``reason`` is the sentence naming the figure that
    fails and its value (empty at level success). ``multipliers`` says which multipliers gave the
    figures: ``"solver"`` (the solver's own, projected on their sign constraints) or
    ``"least-squares"`` (olado's sign-constrained least-squares multipliers). The scaled residuals
    are in relative units of the objective (WORHP's scaled KKT test, seed 000 sec. IV.II [7]):
    ``stationarity_scaled`` = max_i |grad_i L| max(1, |y_i|) / max(1, |J|),
    ``complementarity_scaled`` = max_j |mu_j slack_j| / max(1, |J|). ``gradient_check`` is the
    largest relative error of the derivative spot check (None when it did not run)."""

    level: str
    reason: str = ""
    multipliers: str = ""
    violation: float = float("nan")
    stationarity: float = float("nan")
    complementarity: float = float("nan")
    stationarity_scaled: float = float("nan")
    complementarity_scaled: float = float("nan")
    solver_stationarity_scaled: float = float("nan")
    gradient_check: float | None = None
    gradient_check_note: str = ""
    tol: float = float("nan")
    acceptable_tol: float = float("nan")
    constr_viol_tol: float = float("nan")
    acceptable_constr_viol_tol: float = float("nan")
    time_s: float = 0.0
    evaluations: int = 0

    LEVELS = ("success", "acceptable", "failed")

    @property
    def holds(self) -> bool:
        """True at level success or acceptable."""
        return self.level in ("success", "acceptable")

    def to_dict(self) -> dict:
        return _jsonable(dataclasses.asdict(self))

    def summary(self) -> str:
        """One line for :meth:`Result.summary`."""
        verdict = {"success": "holds", "acceptable": "holds at the acceptable level", "failed": "FAILS"}[self.level]
        figures = (f"scaled stationarity {self.stationarity_scaled:.1e}, complementarity "
                   f"{self.complementarity_scaled:.1e}, violation {self.violation:.1e}")
        if self.gradient_check is not None:
            figures += f", gradient check {self.gradient_check:.1e}"
        text = f"{verdict} ({self.multipliers or 'no'} multipliers): {figures}"
        return text + (f" -- {self.reason}" if self.reason else "")


@dataclasses.dataclass
class Violation:
    """One violated constraint component at a point (olado.solvers.diagnosis): ``array`` is the
    problem's name of the constraint array ("dynamics": f^k(x^k, u^k) - x^{k+1}, "stage_constraints",
    "final_constraints", "x_bounds", "u_bounds", "x0": the fixed initial state), ``stage`` the
    stage index k (None for final_constraints and x0), ``component`` the index in the stage's
    row, ``value`` the violation (> 0: |c| for an equality, -g for g >= 0, the distance to a
    bound) and ``kind`` one of :data:`Violation.KINDS`."""

    array: str
    stage: int | None
    component: int
    value: float
    kind: str

    KINDS = ("equality", "inequality", "lower bound", "upper bound")

    def where(self) -> str:
        """E.g. "stage_constraints[stage 3, component 1]" or "final_constraints[component 0]"."""
        stage = "" if self.stage is None else f"stage {self.stage}, "
        return f"{self.array}[{stage}component {self.component}]"


@dataclasses.dataclass
class ViolatedArray:
    """How much of one constraint array is violated: ``count`` components of ``size`` beyond the
    tolerance, the ``largest`` violation and their ``total`` (l1 sum), at stages
    ``first_stage``..``last_stage`` (None for the arrays without stages)."""

    array: str
    count: int
    size: int
    largest: float
    total: float
    first_stage: int | None = None
    last_stage: int | None = None

    def summary(self) -> str:
        stages = "" if self.first_stage is None else (
            f" at stage {self.first_stage}" if self.first_stage == self.last_stage
            else f" at stages {self.first_stage}..{self.last_stage}")
        return (f"{self.array}: {self.count} of {self.size} components violated{stages}, "
                f"largest {self.largest:.3g}, sum {self.total:.3g}")


@dataclasses.dataclass
class Infeasibility:
    """The diagnosis of an infeasible result (olado.solvers.diagnosis; docs/errors.md,
    "Infeasibility diagnosis"): the constraints that stay violated at the returned point, the
    least-infeasible point the solver found. ``arrays`` has one :class:`ViolatedArray` per
    constraint array with a component violated beyond ``tolerance`` (the solver's
    constr_viol_tol), the largest first; ``violations`` the largest violated components over all
    arrays (at most ``SHOWN`` of them, largest first); ``largest`` and ``total`` the max-norm and
    l1 norm of all violations; ``note`` says why there is no listing (the problem could not be
    evaluated at the point)."""

    tolerance: float
    largest: float = float("nan")
    total: float = float("nan")
    arrays: list = dataclasses.field(default_factory=list)
    violations: list = dataclasses.field(default_factory=list)
    note: str = ""
    time_s: float = 0.0

    #: violated components kept in a Result (and saved) at most; the summary prints LISTED of them
    SHOWN = 20
    LISTED = 5

    @property
    def count(self) -> int:
        """Components violated beyond the tolerance, over all arrays."""
        return sum(a.count for a in self.arrays)

    def to_dict(self) -> dict:
        return _jsonable(dataclasses.asdict(self))

    def summary_lines(self) -> list:
        """The lines of :meth:`Result.summary` (without the field label)."""
        if self.note:
            return [self.note]
        if not self.arrays:
            return [f"no constraint violated beyond {self.tolerance:g} at the returned point"]
        count = self.count
        lines = [f"{count} constraint component{'s' if count != 1 else ''} violated beyond {self.tolerance:g} at "
                 f"the returned point (largest {self.largest:.3g}, l1 sum {self.total:.3g}):"]
        lines += [f"  {a.summary()}" for a in self.arrays]
        shown = self.violations[:self.LISTED]
        lines.append("largest violations:" if len(shown) > 1 else "largest violation:")
        lines += [f"  {v.where()}: {v.value:.3g} ({v.kind})" for v in shown]
        if count > len(shown):
            lines.append(f"  ({len(shown)} of {count} shown)")
        return lines


@dataclasses.dataclass
class Result:
    """Outcome of a solve: see the module docstring for what each field means."""

    status: Status
    message: str
    objective: float
    x: np.ndarray
    u: np.ndarray
    multipliers: dict = dataclasses.field(default_factory=dict)
    max_constraint_violation: float = float("nan")
    kkt_residual: float | None = None
    iterations: int = 0
    qp_iterations: int = 0
    evaluations: dict = dataclasses.field(default_factory=dict)
    time_s: float = 0.0
    history: list = dataclasses.field(default_factory=list)
    problem: str = ""
    N: int = 0
    solver: str = ""
    options: dict = dataclasses.field(default_factory=dict)
    info: dict = dataclasses.field(default_factory=dict)
    certificate: Certificate | None = None
    infeasibility: Infeasibility | None = None

    @property
    def success(self) -> bool:
        return self.status.success

    # ------------------------------------------------------------------ text
    def summary(self) -> str:
        """A short human-readable report."""
        n = self.x.shape[1] if self.x.ndim == 2 else 0
        m = self.u.shape[1] if self.u.ndim == 2 else 0
        lines = [
            f"olado result: {self.problem or 'problem'} (N={self.N}, n={n}, m={m}) solved by {self.solver}",
            f"  status       : {self.status.value} -- {self.message or self.status.sentence}",
            f"  objective    : {self.objective:.12g}",
            f"  max violation: {self.max_constraint_violation:.3e}",
        ]
        if self.kkt_residual is not None:
            lines.append(f"  KKT residual : {self.kkt_residual:.3e}")
        if self.certificate is not None:
            lines.append(f"  certificate  : {self.certificate.summary()}")
        if self.infeasibility is not None:
            first, *rest = self.infeasibility.summary_lines()
            lines.append(f"  infeasible at: {first}")
            lines += [f"                 {line}" for line in rest]
        counts = f"  iterations   : {self.iterations}"
        if self.qp_iterations:
            counts += f" (QP iterations {self.qp_iterations})"
        lines.append(counts)
        if self.evaluations:
            ev = ", ".join(f"{k} {v}" for k, v in self.evaluations.items())
            lines.append(f"  evaluations  : {ev}")
        lines.append(f"  time         : {self.time_s:.3f} s")
        scaling = self.info.get("scaling")
        if scaling:
            cond = scaling.get("condition", {})
            text = (f"{scaling.get('method')}; condition ratio (seed 004 eq. (16)) {cond['ratio']:.3g}: "
                    f"cond {cond['cond_original']:.3g} -> {cond['cond_scaled']:.3g} at the start point"
                    if "ratio" in cond else f"{scaling.get('method')}; {cond.get('note', '')}")
            lines.append(f"  scaling      : {text}")
        if self.info.get("derivatives"):
            lines.append(f"  derivatives  : {self.info['derivatives']}")
        for key in ("callback_time_s", "callback_share"):
            if key in self.info:
                val = self.info[key]
                lines.append(f"  {key:<13}: {val:.3f}" + (" s" if key.endswith("_s") else ""))
        return "\n".join(lines)

    def __str__(self) -> str:  # pragma: no cover - convenience
        return self.summary()

    # ------------------------------------------------------------------ plot
    def plot(self, path=None, problem=None, **kwargs):
        """Plot the trajectories. A problem with a ``plot_result(result, path)`` method (the
        built-in Zambezi problems have one) draws its own figure; otherwise states and controls
        are drawn against the stage index with their finite bounds. Returns the figure."""
        if problem is not None and hasattr(problem, "plot_result"):
            return problem.plot_result(self, path=path, **kwargs)
        import matplotlib

        if path is not None:
            matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
        ks = np.arange(self.x.shape[0])
        axes[0].plot(ks, self.x, marker=".")
        axes[0].set_ylabel("states x")
        axes[1].step(np.arange(self.u.shape[0]), self.u, where="post")
        axes[1].set_ylabel("controls u")
        axes[1].set_xlabel("stage k")
        if problem is not None:
            for arr, ax in ((problem.x_lower, axes[0]), (problem.x_upper, axes[0])):
                for j in range(arr.shape[1]):
                    if np.all(np.isfinite(arr[:, j])):
                        ax.plot(np.arange(arr.shape[0]), arr[:, j], ":", color="gray", lw=0.8)
        fig.suptitle(f"{self.problem} N={self.N} ({self.solver}, {self.status.value}, J={self.objective:.6g})")
        fig.tight_layout()
        if path is not None:
            save_figure(fig, path)
        return fig

    # ------------------------------------------------------------------ save / load
    def to_dict(self) -> dict:
        """JSON-ready dictionary (arrays as nested lists)."""
        d = {
            "problem": self.problem,
            "N": int(self.N),
            "solver": self.solver,
            "status": self.status.value,
            "message": self.message,
            "success": bool(self.success),
            "objective": self.objective,
            "max_constraint_violation": self.max_constraint_violation,
            "kkt_residual": self.kkt_residual,
            "certificate": None if self.certificate is None else self.certificate.to_dict(),
            "infeasibility": None if self.infeasibility is None else self.infeasibility.to_dict(),
            "iterations": int(self.iterations),
            "qp_iterations": int(self.qp_iterations),
            "evaluations": self.evaluations,
            "time_s": self.time_s,
            "options": self.options,
            "info": self.info,
            "history": self.history,
            "x": self.x,
            "u": self.u,
            "multipliers": {k: np.asarray(v) for k, v in self.multipliers.items()},
        }
        return _jsonable(d)

    def save(self, path) -> Path:
        """Save as JSON (``path``) plus an ``.npz`` of the arrays beside it (:func:`write_result`).
        Returns the JSON path."""
        return write_result(self, path)

    @classmethod
    def load(cls, path) -> "Result":
        """Load a result written by :meth:`save` (exact arrays from the npz when it belongs to the
        JSON). Every field is checked: :class:`~olado.errors.ResultFileError` names the file and
        the field of anything that is not what :meth:`save` writes."""
        return cls(**read_result(path))


# ---------------------------------------------------------------------------- the result file
#: the layout :meth:`Result.save` writes; :func:`read_result` reads this version and older ones
FORMAT = "olado-result"
FORMAT_VERSION = 1


def _json_path(path) -> Path:
    if not isinstance(path, (str, os.PathLike)):
        raise ResultFileError(f"expected a file path (str or pathlib.Path), got {type(path).__name__} {path!r:.40}")
    path = Path(path)
    return path if path.suffix.lower() == ".json" else path.with_suffix(".json")


def write_result(result: Result, path) -> Path:
    """The JSON (every field, arrays as nested lists with floats written exactly) and an ``.npz``
    of the arrays beside it, written together by :func:`atomic_write_files`: a failure leaves
    the old pair, a crash between the two replaces a new npz beside the old JSON. Both carry the
    same random ``save_id``; :func:`read_result` takes the npz's arrays only when the ids match,
    so an old JSON is never paired with new arrays."""
    import io
    import uuid

    path = _real_path(_json_path(path))   # through a link: the npz goes beside the real JSON
    save_id = uuid.uuid4().hex
    buf = io.BytesIO()
    arrays = {"x": np.asarray(result.x), "u": np.asarray(result.u), "save_id": np.array(save_id)}
    for k, v in result.multipliers.items():
        arrays[f"multipliers__{k}"] = np.asarray(v)
    np.savez_compressed(buf, **arrays)
    doc = {"format": FORMAT, "format_version": FORMAT_VERSION, **result.to_dict(), "save_id": save_id}
    text = json.dumps(doc, indent=1)
    atomic_write_files([(path.with_suffix(".npz"), buf.getvalue()), (path, text.encode("utf-8"))])
    return path


def read_result(path) -> dict:
    """The keyword arguments of :class:`Result` from a file written by :func:`write_result`,
    every field checked (:data:`RESULT_FIELDS`); ResultFileError naming the file and the field."""
    path = _json_path(path)
    doc = _read_json(path)
    _check_format(doc, path)
    values = {}
    for name, (reader, default) in RESULT_FIELDS.items():
        if name not in doc:
            if default is _REQUIRED:
                raise ResultFileError("missing (a result file written by Result.save has it)", file=path, field=name)
            values[name] = default() if callable(default) else default
            continue
        try:
            values[name] = reader(doc[name])
        except _FieldError as exc:
            raise ResultFileError(str(exc), file=path, field=f"{name}{exc.where}") from None
    _check_consistency(doc, values, path)
    _take_npz_arrays(path, doc.get("save_id"), values)
    return values


def _read_json(path: Path) -> dict:
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise ResultFileNotFoundError("result file not found", file=path) from None
    except UnicodeDecodeError as exc:
        raise ResultFileError(f"not a text file ({exc.reason} at byte {exc.start})", file=path) from None
    except OSError as exc:
        raise ResultFileError(f"cannot read the result file ({exc.strerror or exc})", file=path) from None
    try:
        doc = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as exc:
        raise ResultFileError(f"not a valid olado result file (not JSON: {exc})", file=path) from None
    if not isinstance(doc, dict):
        raise ResultFileError(f"not a valid olado result file (a JSON {_json_type(doc)}, "
                              "expected an object of fields)", file=path)
    return doc


def _check_format(doc: dict, path: Path) -> None:
    fmt = doc.get("format", FORMAT)
    if fmt != FORMAT:
        raise ResultFileError(f"expected {FORMAT!r}, got {fmt!r}", file=path, field="format")
    version = doc.get("format_version", FORMAT_VERSION)  # files of olado 0.1 before versioning: 1
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise ResultFileError(f"expected a positive integer, got {version!r}", file=path, field="format_version")
    if version > FORMAT_VERSION:
        raise ResultFileError(f"version {version} was written by a newer olado; this one reads "
                              f"versions up to {FORMAT_VERSION}", file=path, field="format_version")


def _check_consistency(doc: dict, values: dict, path: Path) -> None:
    """Fields that must agree: the trajectories' lengths, N, and ``success`` with the status."""
    x, u = values["x"], values["u"]
    for name, arr in (("x", x), ("u", u)):
        if arr.ndim != 2 and arr.size:
            raise ResultFileError(f"expected a table (one row of numbers per stage), got {arr.ndim} "
                                  "dimensions", file=path, field=name)
    if x.size and u.size and x.shape[0] != u.shape[0] + 1:
        raise ResultFileError(f"{x.shape[0]} state rows for {u.shape[0]} control rows (expected one more)",
                              file=path, field="x")
    if "N" in doc and u.size and values["N"] != u.shape[0]:
        raise ResultFileError(f"N = {values['N']} but 'u' has {u.shape[0]} rows", file=path, field="N")
    if "success" in doc and not isinstance(doc["success"], bool):
        raise ResultFileError(f"expected true or false, got {_short(doc['success'])}", file=path, field="success")
    if "success" in doc and doc["success"] != values["status"].success:
        raise ResultFileError(f"{doc['success']} does not agree with status {values['status'].value!r}",
                              file=path, field="success")


def _take_npz_arrays(path: Path, save_id, values: dict) -> None:
    """Replace the JSON's arrays by the npz's exact ones when the npz belongs to this JSON."""
    npz = path.with_suffix(".npz")
    if not npz.exists():
        return
    try:
        with np.load(npz, allow_pickle=False) as data:
            if "save_id" not in data.files or str(data["save_id"]) != save_id:
                return  # arrays from another save: keep the JSON's own (exact) values
            arrays = {name: data[name] for name in data.files if name != "save_id"}
    except Exception as exc:  # zip, pickle and format errors of every kind: the file is unusable
        raise ResultFileError(f"cannot read the arrays ({type(exc).__name__}: {exc})", file=npz) from None
    for name, arr in arrays.items():
        field = name.replace("multipliers__", "multipliers.")
        if arr.dtype.kind not in "if":
            raise ResultFileError(f"expected numbers, got dtype {arr.dtype}", file=npz, field=field)
        if name in ("x", "u"):
            if arr.shape != values[name].shape:
                raise ResultFileError(f"shape {arr.shape} differs from the JSON's {values[name].shape}",
                                      file=npz, field=field)
            values[name] = arr
        elif name.startswith("multipliers__"):
            values["multipliers"][name[len("multipliers__"):]] = arr


class _FieldError(Exception):
    """A field's value is not what :func:`write_result` writes (``where``: index inside it)."""

    def __init__(self, message, where=""):
        super().__init__(message)
        self.where = where


def _json_type(value) -> str:
    return {dict: "object", list: "array", str: "string", bool: "boolean", type(None): "null",
            int: "number", float: "number"}.get(type(value), type(value).__name__)


def _read_status(value):
    if not isinstance(value, str):
        raise _FieldError(f"expected a string, got a JSON {_json_type(value)}")
    try:
        return Status(value)
    except ValueError:
        raise _FieldError(f"unknown status {value!r} (known: {', '.join(s.value for s in Status)})") from None


def _read_str(value):
    if not isinstance(value, str):
        raise _FieldError(f"expected a string, got a JSON {_json_type(value)}")
    return value


def _read_count(value):
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise _FieldError(f"expected a non-negative integer, got {value!r}")
    return value


#: how :func:`_jsonable` writes a non-finite float (JSON has no NaN): as a string
_NONFINITE = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}


def _read_float(value):
    if isinstance(value, str) and value.lower() in _NONFINITE:
        return _NONFINITE[value.lower()]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _FieldError(f"expected a number (or 'nan', 'inf'), got {_short(value)}")
    try:
        return float(value)
    except OverflowError:  # an integer beyond the float range
        raise _FieldError(f"the number {_short(value)} is beyond the floating-point range") from None


def _short(value, width=40) -> str:
    text = repr(value)
    return text if len(text) <= width else text[:width - 3] + "..."


def _read_optional_float(value):
    return None if value is None else _read_float(value)


def _read_certificate(value):
    """A saved :class:`Certificate` (null for results written without one); every field checked."""
    if value is None:
        return None
    if not isinstance(value, dict):
        raise _FieldError(f"expected an object or null, got a JSON {_json_type(value)}")
    kw = {}
    for f in dataclasses.fields(Certificate):
        if f.name not in value:
            continue
        v = value[f.name]
        try:
            if f.name in ("level", "reason", "multipliers", "gradient_check_note"):
                kw[f.name] = _read_str(v)
            elif f.name == "evaluations":
                kw[f.name] = _read_count(v)
            else:
                kw[f.name] = _read_optional_float(v) if f.name == "gradient_check" else _read_float(v)
        except _FieldError as exc:
            raise _FieldError(str(exc), where=f".{f.name}") from None
    if kw.get("level") not in Certificate.LEVELS:
        raise _FieldError(f"expected one of {', '.join(Certificate.LEVELS)}, got {kw.get('level')!r}", where=".level")
    return Certificate(**kw)


def _read_optional_count(value):
    return None if value is None else _read_count(value)


def _read_violation_value(value):
    v = _read_float(value)
    if not v >= 0.0:
        raise _FieldError(f"expected a violation >= 0 (or 'inf'), got {_short(value)}")
    return v


def _read_kind(value):
    if _read_str(value) not in Violation.KINDS:
        raise _FieldError(f"expected one of {', '.join(map(repr, Violation.KINDS))}, got {_short(value)}")
    return value


def _read_record(value, cls, readers):
    """A saved dataclass ``cls`` (a JSON object): every field read by its reader in ``readers``;
    a field without a default must be there. Keys the class does not have are ignored (files of
    a newer olado)."""
    if not isinstance(value, dict):
        raise _FieldError(f"expected an object, got a JSON {_json_type(value)}")
    kw = {}
    for f in dataclasses.fields(cls):
        if f.name not in value:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise _FieldError("missing (a result file written by Result.save has it)", where=f".{f.name}")
            continue
        try:
            kw[f.name] = readers[f.name](value[f.name])
        except _FieldError as exc:
            raise _FieldError(str(exc), where=f".{f.name}{exc.where}") from None
    return cls(**kw)


def _read_items(value, item_reader):
    """A JSON array whose items ``item_reader`` reads (the index of a bad one in the field's name)."""
    out = []
    for i, item in enumerate(_read_list(value)):
        try:
            out.append(item_reader(item))
        except _FieldError as exc:
            raise _FieldError(str(exc), where=f"[{i}]{exc.where}") from None
    return out


_VIOLATION_READERS = {"array": _read_str, "stage": _read_optional_count, "component": _read_count,
                      "value": _read_violation_value, "kind": _read_kind}
_VIOLATED_ARRAY_READERS = {"array": _read_str, "count": _read_count, "size": _read_count,
                           "largest": _read_violation_value, "total": _read_violation_value,
                           "first_stage": _read_optional_count, "last_stage": _read_optional_count}


def _read_violated_array(value):
    a = _read_record(value, ViolatedArray, _VIOLATED_ARRAY_READERS)
    if a.count > a.size:
        raise _FieldError(f"{a.count} violated components of {a.size}", where=".count")
    if (a.first_stage is None) != (a.last_stage is None) or (a.first_stage is not None
                                                             and a.first_stage > a.last_stage):
        raise _FieldError(f"stages {a.first_stage}..{a.last_stage} are not a range", where=".first_stage")
    return a


_INFEASIBILITY_READERS = {
    "tolerance": _read_float, "largest": _read_float, "total": _read_float, "note": _read_str,
    "time_s": _read_float,
    "arrays": lambda v: _read_items(v, _read_violated_array),
    "violations": lambda v: _read_items(v, lambda item: _read_record(item, Violation, _VIOLATION_READERS)),
}


def _read_infeasibility(value):
    """A saved :class:`Infeasibility` (null for results without one); every field checked."""
    if value is None:
        return None
    if not isinstance(value, dict):
        raise _FieldError(f"expected an object or null, got a JSON {_json_type(value)}")
    return _read_record(value, Infeasibility, _INFEASIBILITY_READERS)


def _read_dict(value):
    if not isinstance(value, dict):
        raise _FieldError(f"expected a JSON object, got a JSON {_json_type(value)}")
    return value


def _read_list(value):
    if not isinstance(value, list):
        raise _FieldError(f"expected a JSON array, got a JSON {_json_type(value)}")
    return value


def _read_array(value):
    """A (nested) JSON array of numbers -> float array; non-finite entries as _NONFINITE strings."""
    if not isinstance(value, list):
        raise _FieldError(f"expected an array of numbers, got a JSON {_json_type(value)}")
    try:
        raw = np.asarray(value)
    except (ValueError, TypeError) as exc:  # ragged nesting
        raise _FieldError(f"expected a rectangular array of numbers ({str(exc).split('.')[0]})") from None
    if raw.dtype.kind in "if":
        return raw.astype(float)
    entries = np.asarray(value, dtype=object)  # the JSON's own values (strings, null, ...) by index
    out = np.empty(entries.shape)
    for index, entry in np.ndenumerate(entries):
        try:
            out[index] = _read_float(entry)
        except _FieldError as exc:
            raise _FieldError(str(exc), where=str(list(index))) from None
    return out


def _read_multipliers(value):
    out = {}
    for name, arr in _read_dict(value).items():
        try:
            out[name] = _read_array(arr)
        except _FieldError as exc:
            raise _FieldError(str(exc), where=f".{name}{exc.where}") from None
    return out


_REQUIRED = object()

#: Result field -> (reader of its JSON value, default when missing: _REQUIRED, a value or a factory)
RESULT_FIELDS = {
    "status": (_read_status, _REQUIRED),
    "message": (_read_str, ""),
    "objective": (_read_float, _REQUIRED),
    "x": (_read_array, _REQUIRED),
    "u": (_read_array, _REQUIRED),
    "multipliers": (_read_multipliers, dict),
    "max_constraint_violation": (_read_float, math.nan),
    "kkt_residual": (_read_optional_float, None),
    "iterations": (_read_count, 0),
    "qp_iterations": (_read_count, 0),
    "evaluations": (_read_dict, dict),
    "time_s": (_read_float, 0.0),
    "history": (_read_list, list),
    "problem": (_read_str, ""),
    "N": (_read_count, 0),
    "solver": (_read_str, ""),
    "options": (_read_dict, dict),
    "info": (_read_dict, dict),
    "certificate": (_read_certificate, None),
    "infeasibility": (_read_infeasibility, None),
}


def save_figure(fig, path) -> Path:
    """Save a matplotlib figure atomically (format from the file suffix)."""
    import io

    path = Path(path)
    buf = io.BytesIO()
    fmt = path.suffix.lstrip(".").lower() or "png"
    fig.savefig(buf, format=fmt, dpi=120)
    atomic_write_bytes(path, buf.getvalue())
    return path
