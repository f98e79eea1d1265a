"""The instruction list of a CasADi SX function (its algorithm, the one CasADi's C code generator
prints), read for the translations to numba (numba_kernels) and to LLVM IR (llvm_kernels)."""

from __future__ import annotations

from ...errors import ProblemDefinitionError


def instructions(fun, names, target):
    """(k, operation name, inputs, outputs) for every instruction of ``fun`` whose operation is
    one of ``names`` (CasADi's OP_<name> codes); an operation outside them is a
    ProblemDefinitionError naming it and ``target`` (the translation that lacks it)."""
    import casadi as ca   # noqa: PLC0415 - the optional extra
    ops = {getattr(ca, f"OP_{nm}"): nm for nm in names}
    for k in range(fun.n_instructions()):
        op = ops.get(fun.instruction_id(k))
        if op is None:
            raise ProblemDefinitionError(f"the CasADi operation {fun.instruction_id(k)} has no {target} translation; "
                                         "use the back-end option mode='vm'", function="autodiff")
        yield k, op, fun.instruction_input(k), fun.instruction_output(k)
