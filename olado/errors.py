"""The small error hierarchy of olado (docs/architecture.md, "Errors"; which error or status
answers which situation: docs/errors.md).

Non-convergence is never an exception: it is a :class:`olado.result.Status`. Exceptions are for
input that cannot be used (a bad config value, a problem function returning a wrong shape) and
for missing optional components. One of them is also a signal between a problem and a solver:
:class:`NonFiniteEvaluationError`, a NaN or inf where a finite value is needed, which a solver's
line search treats as "step too long" (solvers catch it by type).
"""

from __future__ import annotations


class OladoError(Exception):
    """Root of every error raised on purpose by olado."""


class ConfigError(OladoError, ValueError):
    """A configuration file or option is wrong; the message names file, section, key and the
    allowed values or range where they are known."""

    def __init__(self, message, file=None, section=None, key=None, allowed=None):
        self.file, self.section, self.key, self.allowed = file, section, key, allowed
        where = []
        if file is not None:
            where.append(f"file {file!s}")
        if section is not None:
            where.append(f"section [{section}]")
        if key is not None:
            where.append(f"key '{key}'")
        text = message
        if where:
            text = ", ".join(where) + ": " + message
        if allowed is not None:
            text += f" (allowed: {allowed})"
        super().__init__(text)


class ProblemDefinitionError(OladoError, ValueError):
    """A problem definition is inconsistent: wrong shapes or lengths, non-finite values returned
    by a user function. The message names the function, the stage index and the array."""

    def __init__(self, message, function=None, stage=None, array=None):
        self.function, self.stage, self.array = function, stage, array
        where = []
        if function is not None:
            where.append(f"{function}()")
        if stage is not None:
            where.append(f"stage k={stage}")
        if array is not None:
            where.append(f"array '{array}'")
        text = message if not where else ", ".join(where) + ": " + message
        super().__init__(text)


class NonFiniteEvaluationError(ProblemDefinitionError):
    """A problem function returned, or an array passed to the problem held, a NaN or inf value.

    Raised by the problem's array validation (:meth:`olado.problems.docp.DOCP.check_array` and
    its all-stages counterpart) and by DDP's closed-loop rollout; ``function``, ``stage`` and
    ``array`` name where. At a trial point of a line search it is an evaluation failure the
    solver recovers from (a shorter step); at the initial point it makes the problem unusable.
    Solvers catch it by type, never by message text."""


class SolverError(OladoError, RuntimeError):
    """A solver could not be set up or run (not: did not converge, which is a Result status)."""


class SolverNotAvailableError(SolverError, ImportError):
    """An optional solver backend is not installed; the message says how to install it."""


class AutoDiffNotAvailableError(ProblemDefinitionError, ImportError):
    """A problem written for automatic differentiation (:mod:`olado.problems.autodiff`) needs a
    back-end that is not installed; the message names the optional extra that installs it."""


class ResultFileError(OladoError, ValueError):
    """A saved result (the JSON written by :meth:`olado.result.Result.save`, or the ``.npz``
    beside it) cannot be read: not valid JSON, a newer format version, a missing field or one of
    the wrong type. The message names the file and the field."""

    def __init__(self, message, file=None, field=None):
        self.file, self.field = file, field
        where = []
        if file is not None:
            where.append(f"file {file!s}")
        if field is not None:
            where.append(f"field '{field}'")
        super().__init__(", ".join(where) + ": " + message if where else message)


class ResultFileNotFoundError(ResultFileError, FileNotFoundError):
    """The result file does not exist (also a :class:`FileNotFoundError`)."""


class ProblemInUseError(SolverError):
    """A solve was started on a problem instance that another solve is working on (another
    thread, or a callback of that solve). A problem instance carries per-solve state -- its
    evaluation counters (``problem.counters``), which each solve resets and reports -- so it
    belongs to one solve at a time: give each concurrent solve its own instance."""
