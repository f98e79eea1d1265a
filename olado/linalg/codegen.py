"""The kernel toolkit of olado's compiled layers: fixed-size kernels and LLVM code generation.

Shared by the Riccati kernels (:mod:`olado.linalg.riccati_fixed`) and the interior-point QP's
residual kernel (:mod:`olado.qp.interior_point.kkt_map`), and by nothing else: an internal layer
whose names are public only because two packages use them (not a user-facing API).

Stage blocks are tiny (n, m ~ 5..10), so what the compiler knows about the sizes matters more
than the flop count. A kernel compiled "for the sizes" receives *size tags* (:func:`size_tags`):
tuples whose lengths are the sizes -- numba specializes on the tuple type and ``len`` of a tuple
is a compile-time constant -- so its stage loops have constant trip counts and its stage
workspaces live on the stack (:func:`stack_matrix`, :func:`stack_vector`), where LLVM knows they
alias nothing and keeps them in registers. Blocks with n + m <= :data:`FIXED_SIZE_MAX` get such
kernels (:func:`fixed_size_tags`); larger ones the any-size kernels.

numba runs LLVM without its SLP vectorizer, and LLVM's loop vectorizer never sees loops of a
few constant trips (they are unrolled first), so loops over the rows of a stage stay scalar
however they are ordered. The stage intrinsics therefore write straight-line SIMD code
themselves, with the helpers here: a row is a list of *pieces* (first column, width, LLVM
value: a double or a vector of 2 or 4 doubles, :func:`pieces`), and :class:`RowCode` /
:class:`ContractRowCode` emit loads, stores, axpys and transposing row reductions on them.

numba caches a compiled kernel on disk keyed on the kernel's own source file and signature, not
on the modules whose code it inlines: after a change of the code generated here, the kernels of
other files would keep their old generated code. So every kernel compiled for the sizes takes
the size tags, and the size tags carry :data:`KERNEL_VERSION` as a fourth tag of that length:
the version is part of each kernel's signature, and a new version is a new signature, compiled
afresh (the old cache entries are never loaded again).
"""

from __future__ import annotations

import collections
import os

import numba as nb
import numpy as np
from llvmlite import ir as llir
from numba import types
from numba.core import cgutils
from numba.core.imputils import impl_ret_borrowed
from numba.extending import intrinsic

#: numba fastmath flags of the kernels: multiply-adds may be contracted to FMAs (CONTRACT), and
#: reductions reassociated as well (REASSOC); no other fast-math, so NaN and inf still propagate
CONTRACT = {"contract"}
REASSOC = {"reassoc", "contract", "nsz"}
#: blocks with n + m up to this get the kernels compiled for their sizes
FIXED_SIZE_MAX = 24
#: version of the generated code: bump it with every change of what this module generates (or
#: of the code it inlines into the kernels), so that numba's on-disk caches of the kernels that
#: use it are not loaded again (see the module docstring)
KERNEL_VERSION = 1

#: the fields of the size tags of a kernel compiled for stage blocks of n states and m controls:
#: tuples of zeros of the lengths n, m, n + m and KERNEL_VERSION (see size_tags, as_bundle)
SizeTags = collections.namedtuple("SizeTags", "n m nz version")



@intrinsic
def stack_buffer(typingctx, tags):
    """Pointer to a float64 buffer on the stack of the calling kernel, of size the product of
    the lengths of the size tags (known at compile time)."""
    size = 1
    for tag in tags:
        size *= len(tag)

    def codegen(context, builder, signature, args):
        return cgutils.alloca_once(builder, context.get_value_type(types.float64),
                                   size=context.get_constant(types.intp, size))
    return types.CPointer(types.float64)(tags), codegen


@nb.njit(inline="always")
def stack_matrix(rows, cols):
    """A (len(rows), len(cols)) workspace on the stack (contents undefined)."""
    return nb.carray(stack_buffer((rows, cols)), (len(rows), len(cols)))


@nb.njit(inline="always")
def stack_vector(rows):
    """A (len(rows),) workspace on the stack (contents undefined)."""
    return nb.carray(stack_buffer((rows,)), (len(rows),))


def size_tags(n, m):
    """The size tags of the kernels compiled for stage blocks of n states and m controls, a
    plain tuple with the fields of SizeTags: for each of n, m, n + m a tuple of zeros of that
    length (numba specializes on the lengths, which are compile-time constants in the kernel),
    and the version tag of length KERNEL_VERSION."""
    return tuple(SizeTags((0,) * n, (0,) * m, (0,) * (n + m), (0,) * KERNEL_VERSION))


@intrinsic
def as_bundle(typingctx, tup, cls):
    """The tuple ``tup`` as an instance of the namedtuple class ``cls`` (same members, no copy):
    kernels take their bundles of arrays as plain tuples -- numba's dispatcher types a plain
    tuple about as fast as the arrays one by one, a namedtuple several microseconds slower per
    call -- and read them by the field names of the bundle's class, declared once."""
    if not (isinstance(tup, types.BaseTuple) and isinstance(cls, types.NamedTupleClass)
            and len(tup) == len(cls.instance_class._fields)):
        return None
    bundle = types.BaseTuple.from_types(list(tup), cls.instance_class)

    def codegen(context, builder, signature, args):
        return impl_ret_borrowed(context, builder, signature.return_type, args[0])
    return bundle(tup, cls), codegen


def fixed_size_tags(n, m):
    """size_tags(n, m) for blocks that get the kernels compiled for their sizes (0 < n, 0 < m,
    n + m <= FIXED_SIZE_MAX), else None."""
    return size_tags(n, m) if 0 < n and 0 < m and n + m <= FIXED_SIZE_MAX else None


# ----------------------------------------------------------------------------- bound kernels
#: environment variable: when set (not "0"), every call of a bound kernel types its arguments and
#: compares them with the signature it was bound to (the test suite sets it, see KernelSet)
CHECK_TYPES_ENV = "OLADO_CHECK_KERNEL_TYPES"


class KernelTypeError(TypeError):
    """A bound kernel was called with arguments of other types than those it was bound to (an
    internal error: a caller broke the invariant of :class:`KernelSet`)."""


def entry_point(kernel, args):
    """The compiled entry point of the numba dispatcher ``kernel`` for the types of ``args`` (it
    must have been called with such arguments), or the dispatcher itself if numba does not
    expose it."""
    try:
        return kernel.overloads[tuple(kernel.typeof_pyval(a) for a in args)].entry_point
    except (AttributeError, KeyError, TypeError):
        return kernel


class _FirstCall:
    """A kernel of a KernelSet before its first call: the call goes through numba's dispatcher
    (which compiles or loads the kernel), then the set's attribute becomes the entry point."""

    __slots__ = ("owner", "name", "kernel")

    def __init__(self, owner, name, kernel):
        self.owner, self.name, self.kernel = owner, name, kernel

    def __call__(self, *args):
        bound = getattr(self.owner, self.name)
        if bound is not self:   # bound since this object was looked up
            return bound(*args)
        result = self.kernel(*args)
        entry = entry_point(self.kernel, args)
        if os.environ.get(CHECK_TYPES_ENV, "0") not in ("", "0"):
            entry = _Checked(self.kernel, args, entry)
        setattr(self.owner, self.name, entry)
        return result


def _layout(kernel, a):
    """What numba's type of the argument ``a`` depends on, computed in Python: for an array its
    dtype, rank, layout flags and writeability, for a tuple (a bundle) its members', for a Python
    or numpy scalar its type (and for an int whether it fits int64), numba's type otherwise.
    ~25x cheaper than numba's typeof of a bundle of a dozen arrays (4 us against 114 us), which
    made the checked test runs of long solves 16x slower than unchecked; the scalars' keys halve
    what is left (zambezi12 N = 72, sqp-ip: 73 ms checked -> 43 ms, 32 ms unchecked)."""
    if isinstance(a, np.ndarray):
        flags = a.flags
        return a.dtype.num, a.ndim, flags.c_contiguous, flags.f_contiguous, flags.writeable, flags.aligned
    if isinstance(a, tuple):
        return tuple(_layout(kernel, x) for x in a)
    kind = type(a)
    if kind is float or kind is bool:   # numba: float64, boolean
        return kind
    if kind is int:                     # numba: int64, or uint64 beyond its range
        return kind, a.bit_length() > 63
    if isinstance(a, np.generic):
        return a.dtype.num
    return kernel.typeof_pyval(a)


class _Checked:
    """A bound kernel that checks the types of every call's arguments (CHECK_TYPES_ENV)."""

    __slots__ = ("kernel", "signature", "layout", "entry")

    def __init__(self, kernel, args, entry):
        self.kernel, self.entry = kernel, entry
        self.signature = tuple(kernel.typeof_pyval(a) for a in args)
        self.layout = tuple(_layout(kernel, a) for a in args)

    def __call__(self, *args):
        if tuple(_layout(self.kernel, a) for a in args) != self.layout:
            signature = tuple(self.kernel.typeof_pyval(a) for a in args)
            diff = [i for i, (a, b) in enumerate(zip(signature, self.signature)) if a != b]
            if diff:
                raise KernelTypeError(f"{self.kernel.__name__} bound to {self.signature} called with other types "
                                      f"at arguments {diff}: {[signature[i] for i in diff]}")
        return self.entry(*args)


class KernelSet:
    """Compiled kernels called through their entry points, without numba's per-call typing.

    numba's dispatcher types every argument of every call to find the compiled version for
    them: cheap for an array, several hundred nanoseconds for a bundle (a tuple of arrays, typed
    through a fingerprint of all its members) -- at small N, where a QP iteration is a few dozen
    kernel calls on short arrays, that typing was about 5 % of the SQP's time. A KernelSet holds
    kernels whose callers pass arguments of fixed types: after a kernel's first call through the
    dispatcher, its attribute is the compiled entry point for that call's types, which the later
    calls reach directly.

    The invariant is the caller's: every call of a set's kernel passes arguments of the types of
    the first call. The stage arrays are C-contiguous float64 by construction (StageData,
    StageQP and the prepared QP make them so), so their types depend on nothing but the size
    tags of the kernels compiled for the block sizes: :func:`kernel_set` keeps one set per
    (kernel table, size key). With CHECK_TYPES_ENV set (the test suite does), every call is
    checked against the first one's types and a difference raises KernelTypeError."""

    def __init__(self, kernels):
        for name, kernel in kernels.items():
            setattr(self, name, _FirstCall(self, name, kernel))


_KERNEL_SETS: dict = {}


def kernel_set(kernels: dict, key=None) -> KernelSet:
    """The KernelSet of the kernels ``kernels`` ({name: dispatcher}, a module-level table) for
    the argument types named by ``key`` (e.g. the block sizes (n, m) of kernels that take size
    tags; None when the types do not depend on the sizes), made at the first request."""
    ks = _KERNEL_SETS.get((id(kernels), key))
    if ks is None:
        ks = _KERNEL_SETS[(id(kernels), key)] = KernelSet(kernels)
    return ks


F64 = llir.DoubleType()
I32 = llir.IntType(32)
I64 = llir.IntType(64)


def pieces(first, count):
    """(first column, width) of the pieces of 4, 2 and 1 doubles covering count columns."""
    out, c, end = [], first, first + count
    while end - c >= 4:
        out.append((c, 4))
        c += 4
    if end - c >= 2:
        out.append((c, 2))
        c += 2
    if end - c == 1:
        out.append((c, 1))
    return out


class RowCode:
    """Code generation on rows of pieces (the stage intrinsics of the Riccati kernels and of the
    interior-point QP's residual kernel). A row is a list of pieces (first column, width, LLVM
    value: a double or a vector of 2 or 4 doubles), data pointers point to C-ordered float64
    matrices of ncols columns.

    A change of the code these helpers generate needs a new KERNEL_VERSION (module docstring)."""

    def __init__(self, builder):
        self.b = builder

    def _ptr(self, data, ncols, i, j, w):
        p = self.b.gep(data, [llir.Constant(llir.IntType(64), i * ncols + j)])
        return p if w == 1 else self.b.bitcast(p, llir.VectorType(F64, w).as_pointer())

    def load(self, data, ncols, i, j, w=1):
        return self.b.load(self._ptr(data, ncols, i, j, w), align=8)

    def store(self, v, data, ncols, i, j, w=1):
        self.b.store(v, self._ptr(data, ncols, i, j, w), align=8)

    def splat(self, x, w):
        if w == 1:
            return x
        v = self.b.insert_element(llir.Constant(llir.VectorType(F64, w), llir.Undefined), x,
                                  llir.Constant(I32, 0))
        return self.b.shuffle_vector(v, v, llir.Constant(llir.VectorType(I32, w), [0] * w))

    def entry(self, row, col):
        for c0, w, v in row:
            if c0 <= col < c0 + w:
                return v if w == 1 else self.b.extract_element(v, llir.Constant(I32, col - c0))
        raise IndexError(col)

    def axpy(self, row, a, x):
        """row + a x, on the pieces of row (x has those pieces, maybe more)."""
        xv = {c0: v for c0, w, v in x}
        return [(c0, w, self.b.fadd(v, self.b.fmul(self.splat(a, w), xv[c0]))) for c0, w, v in row]

    def scale(self, row, a):
        return [(c0, w, self.b.fmul(self.splat(a, w), v)) for c0, w, v in row]


class ContractRowCode(RowCode):
    """RowCode with contracted arithmetic (LLVM may fuse a multiply and an add), lane extraction
    and the transposing row reduction: what the Riccati solve sweeps and the QP's _kkt_stage share."""

    def vtype(self, w):
        return F64 if w == 1 else llir.VectorType(F64, w)

    def add(self, a, b):
        return self.b.fadd(a, b, flags=("contract",))

    def sub(self, a, b):
        return self.b.fsub(a, b, flags=("contract",))

    def mul(self, a, b):
        return self.b.fmul(a, b, flags=("contract",))

    def axpy(self, row, a, x):
        xv = {c0: v for c0, w, v in x}
        return [(c0, w, self.add(v, self.mul(self.splat(a, w), xv[c0]))) for c0, w, v in row]

    def lanes(self, v, first, w):
        """Lanes first..first+w-1 of the vector v."""
        if w == 1:
            return self.b.extract_element(v, llir.Constant(I32, first))
        return self.b.shuffle_vector(v, v, llir.Constant(llir.VectorType(I32, w), list(range(first, first + w))))

    def row_sums(self, rows, W):
        """Lane i = the sum of the lanes of rows[i] (len(rows) <= W vectors of W lanes; the other
        lanes undefined): pairwise shuffles and adds, a transposing reduction."""
        if W == 1:
            return rows[0]
        L = list(rows) + [llir.Constant(self.vtype(W), llir.Undefined)] * (W - len(rows))
        b = 1
        while len(L) > 1:
            # lane order: P's block 2j, Q's block 2j, ... (ev) and the odd blocks (od)
            ev = [x for j in range(W // (2 * b)) for x in
                  [2 * j * b + t for t in range(b)] + [W + 2 * j * b + t for t in range(b)]]
            od = [x for j in range(W // (2 * b)) for x in
                  [(2 * j + 1) * b + t for t in range(b)] + [W + (2 * j + 1) * b + t for t in range(b)]]
            ev, od = (llir.Constant(llir.VectorType(I32, W), idx) for idx in (ev, od))
            L = [self.add(self.b.shuffle_vector(L[i], L[i + 1], ev), self.b.shuffle_vector(L[i], L[i + 1], od))
                 for i in range(0, len(L), 2)]
            b *= 2
        return L[0]


def c_arrays(*arrs, ndim):
    """Whether the numba types arrs are C-contiguous float64 arrays of the dimensions ndim."""
    return all(isinstance(a, types.Array) and a.ndim == nd and a.dtype == types.float64 and a.layout == "C"
               for a, nd in zip(arrs, ndim))


def stage_pointers(builder, k, data, where):
    """{name: pointer to stage k (+ offset) of an array} for where = {name: (array data pointer,
    stage offset, elements per stage)}."""
    out = {}
    for name, (ptr, off, size) in where.items():
        i = builder.mul(builder.add(k, llir.Constant(I64, off)), llir.Constant(I64, size))
        out[name] = builder.gep(ptr, [i])
    return out


def carry_slots(builder, row_pieces):
    """Stack slots for values carried from one iteration of a sweep to the next (promoted to
    registers by LLVM)."""
    return [(c0, w, cgutils.alloca_once(builder, F64 if w == 1 else llir.VectorType(F64, w)))
            for c0, w in row_pieces]


def as_i64(builder, v):
    """The LLVM integer v as i64."""
    return builder.sext(v, I64) if v.type.width < 64 else v
