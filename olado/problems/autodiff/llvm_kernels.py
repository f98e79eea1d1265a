"""CasADi SX functions translated to LLVM IR (a loop over the stages) and compiled by llvmlite,
numba's own dependency: no C compiler, a fraction of a second of set-up."""

from __future__ import annotations

from .object_cache import function_key, load_object, object_key, store_object
from .sx import instructions


_LLVM_LIBM1 = {"EXP": "exp", "LOG": "log", "SQRT": "sqrt", "SIN": "sin", "COS": "cos", "TAN": "tan",
               "ASIN": "asin", "ACOS": "acos", "ATAN": "atan", "SINH": "sinh", "COSH": "cosh",
               "TANH": "tanh", "ASINH": "asinh", "ACOSH": "acosh", "ATANH": "atanh", "FABS": "fabs",
               "FLOOR": "floor", "CEIL": "ceil", "ERF": "erf", "LOG1P": "log1p", "EXPM1": "expm1"}
_LLVM_LIBM2 = {"POW": "pow", "CONSTPOW": "pow", "ATAN2": "atan2", "FMOD": "fmod", "COPYSIGN": "copysign",
               "HYPOT": "hypot", "FMIN": "fmin", "FMAX": "fmax"}
_LLVM_ARITH = {"ADD": "fadd", "SUB": "fsub", "MUL": "fmul", "DIV": "fdiv"}
_LLVM_CMP = {"LT": "<", "LE": "<=", "EQ": "=="}
#: the execution engines of the compiled kernels (a kernel's code lives as long as its engine)
#: and the kernels' addresses by their cache key (object_cache.function_key): a model built
#: again in the same process is not compiled again
_ENGINES = []
_COMPILED = {}


def sx_llvm_ir(fun):
    """LLVM IR (text) of ``void kernel(i64 K, double* a0, ..., double* r0, ...)``: a loop over the
    K stages evaluating the CasADi SX function ``fun`` -- its instruction list (the algorithm
    CasADi's C code generator prints) as one SSA value per instruction, the elementary functions
    as calls to the C math library. Argument j is a C-contiguous (K, nnz_in(j)) array, result j
    a (K, nnz_out(j)) array, entries in CasADi's column-major nonzero order."""
    from llvmlite import ir   # noqa: PLC0415 - numba's own dependency
    names = (["ASSIGN", "NEG", "SQ", "TWICE", "INV", "CONST", "INPUT", "OUTPUT", "SIGN", "NOT", "NE",
              "AND", "OR", "IF_ELSE_ZERO"] + list(_LLVM_CMP) + list(_LLVM_ARITH) + list(_LLVM_LIBM1)
             + list(_LLVM_LIBM2))
    dbl, i64 = ir.DoubleType(), ir.IntType(64)
    n_in, n_out = fun.n_in(), fun.n_out()
    module = ir.Module(name="olado_ad")
    kernel = ir.Function(module, ir.FunctionType(ir.VoidType(), [i64] + [dbl.as_pointer()] * (n_in + n_out)),
                         name="kernel")
    libm = {}

    def call(b, name, *args):
        if name not in libm:
            libm[name] = ir.Function(module, ir.FunctionType(dbl, [dbl] * len(args)), name=name)
        return b.call(libm[name], list(args))

    entry, loop, done = (kernel.append_basic_block(nm) for nm in ("entry", "loop", "done"))
    b = ir.IRBuilder(entry)
    K = kernel.args[0]
    b.cbranch(b.icmp_signed(">", K, i64(0)), loop, done)
    b.position_at_end(loop)
    i = b.phi(i64)
    i.add_incoming(i64(0), entry)
    rows_in = [b.gep(kernel.args[1 + j], [b.mul(i, i64(fun.nnz_in(j)))]) for j in range(n_in)]
    rows_out = [b.gep(kernel.args[1 + n_in + j], [b.mul(i, i64(fun.nnz_out(j)))]) for j in range(n_out)]
    zero, one = dbl(0.0), dbl(1.0)
    truth = lambda v: b.fcmp_unordered("!=", v, zero)   # noqa: E731 - nonzero (NaN counts), as in C
    w = {}
    for k, op, ins, outs in instructions(fun, names, "LLVM"):
        a = w.get(ins[0]) if ins else None
        c = w.get(ins[1]) if len(ins) > 1 else None
        if op == "OUTPUT":
            b.store(a, b.gep(rows_out[outs[0]], [i64(outs[1])]))
            continue
        if op == "INPUT":
            v = b.load(b.gep(rows_in[ins[0]], [i64(ins[1])]))
        elif op == "CONST":
            v = dbl(fun.instruction_constant(k))
        elif op == "ASSIGN":
            v = a
        elif op == "NEG":
            v = b.fneg(a)
        elif op == "SQ":
            v = b.fmul(a, a)
        elif op == "TWICE":
            v = b.fadd(a, a)
        elif op == "INV":
            v = b.fdiv(one, a)
        elif op in _LLVM_ARITH:
            v = getattr(b, _LLVM_ARITH[op])(a, c)
        elif op in _LLVM_CMP:
            v = b.uitofp(b.fcmp_ordered(_LLVM_CMP[op], a, c), dbl)
        elif op == "NE":
            v = b.uitofp(b.fcmp_unordered("!=", a, c), dbl)
        elif op == "NOT":
            v = b.uitofp(b.fcmp_ordered("==", a, zero), dbl)
        elif op in ("AND", "OR"):
            v = b.uitofp(b.and_(truth(a), truth(c)) if op == "AND" else b.or_(truth(a), truth(c)), dbl)
        elif op == "IF_ELSE_ZERO":
            v = b.select(truth(a), c, zero)
        elif op == "SIGN":
            v = b.select(b.fcmp_ordered(">", a, zero), one, b.select(b.fcmp_ordered("<", a, zero), dbl(-1.0), a))
        elif op in _LLVM_LIBM1:
            v = call(b, _LLVM_LIBM1[op], a)
        else:
            v = call(b, _LLVM_LIBM2[op], a, c)
        w[outs[0]] = v
    step = b.add(i, i64(1))
    i.add_incoming(step, b.block)
    b.cbranch(b.icmp_signed("<", step, K), loop, done)
    b.position_at_end(done)
    b.ret_void()
    return str(module)


class LLVMKernel:
    """A kernel compiled from :func:`sx_llvm_ir` by LLVM (llvmlite, numba's own dependency: no C
    compiler), called like the numba kernels: kernel(*arrays), every array a C-contiguous
    float64 (K, size) matrix (through the compiled trampoline of :mod:`.trampoline`)."""

    def __init__(self, fun):
        from .trampoline import call_kernel   # noqa: PLC0415 - loads numba
        key = function_key(fun)
        self.call = call_kernel
        self.address = _COMPILED.get(key)
        if self.address is None:        # not compiled before in this process
            self.address = _COMPILED[key] = compile_ir(lambda: sx_llvm_ir(fun), key)

    def __call__(self, *arrays):
        self.call(self.address, arrays)


def compile_ir(text, key=None):
    """The address of ``kernel`` compiled from the IR ``text`` (a string, or a callable returning
    it, called only when the object code is not cached; ``key`` then names it, by default
    :func:`object_key` of the text). Its engine is kept in _ENGINES. The machine code comes from
    the disk cache (:mod:`.object_cache`) when an intact entry exists, else from LLVM's
    optimization pipeline (speed level 2, O3 code generation), the object code then stored for
    the next run."""
    import llvmlite.binding as llvm   # noqa: PLC0415
    llvm.initialize_native_target()
    llvm.initialize_native_asmprinter()
    machine = llvm.Target.from_default_triple().create_target_machine(opt=3)
    key = key or object_key(text)
    cached = load_object(key)
    if cached is not None:
        address = _engine_address(machine, _empty_module(machine), cached, [])
        if address:
            return address
    module = llvm.parse_assembly(text() if callable(text) else text)
    module.verify()
    builder = llvm.create_pass_builder(machine, llvm.create_pipeline_tuning_options(speed_level=2))
    builder.getModulePassManager().run(module, builder)
    compiled = []
    address = _engine_address(machine, module, None, compiled)
    if compiled:
        store_object(key, compiled[0])
    return address


def _empty_module(machine):
    """An empty module for the target: MCJIT loads the cached object code in its place (numba
    loads its cached functions the same way)."""
    import llvmlite.binding as llvm   # noqa: PLC0415
    module = llvm.parse_assembly("")
    module.triple, module.data_layout = machine.triple, str(machine.target_data)
    return module


def _engine_address(machine, module, cached, compiled):
    """Finalize an MCJIT engine for ``module`` with the object cache hooks (``cached``: the object
    code to load instead of generating it; ``compiled`` collects the generated object code) and
    return the address of ``kernel`` (0 when absent)."""
    import llvmlite.binding as llvm   # noqa: PLC0415
    engine = llvm.create_mcjit_compiler(module, machine)
    engine.set_object_cache(lambda _module, buf: compiled.append(bytes(buf)), lambda _module: cached)
    engine.finalize_object()
    address = engine.get_function_address("kernel")
    if address:
        _ENGINES.append(engine)
    return address
