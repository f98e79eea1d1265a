"""The one result type every olado solver returns (docs/architecture.md, "The solver side").

A :class:`Result` carries the status (an enum with a human sentence), the state and control
trajectories, multipliers, objective, constraint violation, KKT residual, counts, timings and the
per-iteration history. It prints a summary, plots itself and saves/loads as JSON + npz, written
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

from .errors import OladoError


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


def _float_or_nan(value):
    if value is None:
        return None
    if isinstance(value, str):
        return float(value)
    return float(value)


def atomic_write_bytes(path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder and os.replace."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)   # mkstemp creates 0600; a saved result is an ordinary file
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


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

    @classmethod
    def from_dict(cls, d) -> "Certificate | None":
        """The certificate of a saved result (None for files written without one)."""
        if not isinstance(d, dict) or d.get("level") not in cls.LEVELS:
            return None
        kw = {}
        for f in dataclasses.fields(cls):
            if f.name not in d:
                continue
            v = d[f.name]
            if f.name in ("level", "reason", "multipliers", "gradient_check_note"):
                kw[f.name] = str(v)
            elif f.name == "evaluations":
                kw[f.name] = int(v)
            else:
                kw[f.name] = None if v is None else float(v)
        return cls(**kw)

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
        counts = f"  iterations   : {self.iterations}"
        if self.qp_iterations:
            counts += f" (QP iterations {self.qp_iterations})"
        lines.append(counts)
        if self.evaluations:
            ev = ", ".join(f"{k} {v}" for k, v in self.evaluations.items())
            lines.append(f"  evaluations  : {ev}")
        lines.append(f"  time         : {self.time_s:.3f} s")
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
        """Save as JSON (``path``) plus an ``.npz`` of the arrays beside it, each written
        atomically (temporary file + os.replace).

        Both files carry the same random ``save_id``; :meth:`load` uses the npz only when the
        ids match, so a crash between the two writes never pairs an old JSON with new arrays
        (the JSON itself holds every array, with floats written exactly). Returns the JSON path."""
        path = Path(path)
        if path.suffix.lower() != ".json":
            path = path.with_suffix(".json")
        import io

        import uuid

        save_id = uuid.uuid4().hex
        buf = io.BytesIO()
        arrays = {"x": np.asarray(self.x), "u": np.asarray(self.u), "save_id": np.array(save_id)}
        for k, v in self.multipliers.items():
            arrays[f"multipliers__{k}"] = np.asarray(v)
        np.savez_compressed(buf, **arrays)
        atomic_write_bytes(path.with_suffix(".npz"), buf.getvalue())
        doc = self.to_dict()
        doc["save_id"] = save_id
        text = json.dumps(doc, indent=1)
        atomic_write_bytes(path, text.encode("utf-8"))
        return path

    @classmethod
    def load(cls, path) -> "Result":
        """Load a result written by :meth:`save` (exact arrays from the npz when present)."""
        path = Path(path)
        if path.suffix.lower() != ".json":
            path = path.with_suffix(".json")
        try:
            d = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise
        except json.JSONDecodeError as exc:
            raise OladoError(f"{path}: not a valid olado result file ({exc})") from exc
        x = np.asarray(d["x"], dtype=float)
        u = np.asarray(d["u"], dtype=float)
        mult = {k: np.asarray(v, dtype=float) for k, v in d.get("multipliers", {}).items()}
        npz = path.with_suffix(".npz")
        if npz.exists():
            with np.load(npz) as data:
                if "save_id" not in data.files or str(data["save_id"]) != d.get("save_id"):
                    data = None  # arrays from another save: keep the JSON's own (exact) values
                if data is not None:
                    x, u = data["x"], data["u"]
                    for name in data.files:
                        if name.startswith("multipliers__"):
                            mult[name[len("multipliers__"):]] = data[name]
        return cls(
            status=Status(d["status"]),
            message=d.get("message", ""),
            objective=_float_or_nan(d["objective"]),
            x=x,
            u=u,
            multipliers=mult,
            max_constraint_violation=_float_or_nan(d.get("max_constraint_violation", "nan")),
            kkt_residual=_float_or_nan(d.get("kkt_residual")),
            iterations=int(d.get("iterations", 0)),
            qp_iterations=int(d.get("qp_iterations", 0)),
            evaluations=d.get("evaluations", {}),
            time_s=float(d.get("time_s", 0.0)),
            history=d.get("history", []),
            problem=d.get("problem", ""),
            N=int(d.get("N", 0)),
            solver=d.get("solver", ""),
            options=d.get("options", {}),
            info=d.get("info", {}),
            certificate=Certificate.from_dict(d.get("certificate")),
        )


def save_figure(fig, path) -> Path:
    """Save a matplotlib figure atomically (format from the file suffix)."""
    import io

    path = Path(path)
    buf = io.BytesIO()
    fmt = path.suffix.lstrip(".").lower() or "png"
    fig.savefig(buf, format=fmt, dpi=120)
    atomic_write_bytes(path, buf.getvalue())
    return path
