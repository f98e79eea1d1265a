"""The vector operations a model builder (:class:`~olado.problems.ocp.OCP`) writes its stage
with, for the back-end it runs on: CasADi SX column vectors, or numpy arrays (size, K) over the
stages (:class:`~.numpy_backend.NumpyOps`)."""

from __future__ import annotations

import numpy as np

from .numpy_backend import NumpyOps


class CasadiOps:
    """The operations on CasADi SX column vectors (casadi imported on first use)."""

    name = "casadi"

    def __init__(self):
        import casadi   # noqa: PLC0415 - the optional extra
        self.ca = casadi

    def sym(self, name, size, sample):
        return self.ca.SX.sym(name, size)

    @staticmethod
    def entries(value):
        from .model import StageModel   # noqa: PLC0415
        return StageModel._entries(value)

    def vertcat(self, *items):
        ca = self.ca
        parts = [it if isinstance(it, (ca.SX, ca.DM)) else ca.SX(it) for it in items]
        return ca.vertcat(*parts) if parts else ca.SX(0, 1)

    def empty(self):
        return self.ca.SX(0, 1)

    def scalar(self, value):
        return self.ca.SX(value)

    def const(self, values):
        return self.ca.DM(np.asarray(values, dtype=float))

    def sumsqr(self, v):
        return self.ca.sumsqr(v)


def vector_ops(backend):
    """The operations for the back-end ``backend`` ("casadi" or "numpy")."""
    return CasadiOps() if backend == "casadi" else NumpyOps()
