"""The disk cache of the LLVM kernels' machine code (:mod:`.llvm_kernels`): llvmlite's
``ExecutionEngine.set_object_cache`` hands MCJIT the object code compiled by an earlier run, so a
model built again skips LLVM's optimization and code generation (most of its set-up time).

An entry is named by the SHA-256 of what the kernel is compiled from -- the CasADi function's
serialization (its algorithm, every constant to the bit) with the CasADi version and the source
of the translation to IR (:func:`function_key`), or the IR text itself -- and of the llvmlite
and LLVM versions, the target triple, host CPU and features and the pipeline settings
(:func:`object_key`): the user's data baked into the function are part of the key. It holds a
magic line, the SHA-256 of the object code and the object code, and is written atomically (a
temporary file, then ``os.replace``), so concurrent processes never see half a file. An entry
that cannot be read or whose digest does not match is ignored, and the kernel is compiled and
stored again. ``OLADO_KERNEL_CACHE=0`` (or no writable cache directory) turns the cache off."""

from __future__ import annotations

import functools
import hashlib
import os

from .numba_kernels import cache_directory

#: bump when the IR -> object pipeline of LLVMKernel changes (part of every key)
PIPELINE = "mcjit-opt3-speed2-v1"
_MAGIC = b"olado-llvm-object-1\n"


@functools.lru_cache(maxsize=None)
def _target_signature():
    """Text naming the code generator: llvmlite and LLVM versions, triple, host CPU, features."""
    import llvmlite   # noqa: PLC0415
    import llvmlite.binding as llvm   # noqa: PLC0415
    try:
        features = llvm.get_host_cpu_features().flatten()
    except RuntimeError:       # not available on every platform
        features = "?"
    return "\n".join([PIPELINE, llvmlite.__version__, ".".join(map(str, llvm.llvm_version_info)),
                      llvm.get_default_triple(), llvm.get_host_cpu_name(), features])


def object_key(source):
    """The cache key of the kernel compiled from ``source`` (its IR text, or any text that fixes
    the IR: :func:`function_key`) on this machine (hex SHA-256)."""
    digest = hashlib.sha256(_target_signature().encode("utf-8"))
    digest.update(b"\0")
    digest.update(source.encode("utf-8"))
    return digest.hexdigest()


@functools.lru_cache(maxsize=None)
def _translator_signature():
    """CasADi's version and the source of the SX -> IR translation (llvm_kernels.py, sx.py)."""
    import casadi   # noqa: PLC0415
    digest = hashlib.sha256(casadi.__version__.encode("utf-8"))
    here = os.path.dirname(os.path.abspath(__file__))
    for name in ("llvm_kernels.py", "sx.py"):
        with open(os.path.join(here, name), "rb") as fh:
            digest.update(fh.read())
    return digest.hexdigest()


def function_key(fun):
    """The cache key of the kernel of the CasADi SX function ``fun`` (:func:`object_key` of its
    serialization and the translator): known without translating ``fun`` to IR, which is most
    of the set-up left once the object code is cached (hashing serializes in C++, 20x faster)."""
    return object_key("casadi-sx\0" + _translator_signature() + "\0" + fun.serialize())


def _path(key):
    directory = cache_directory()
    return None if directory is None else os.path.join(directory, f"llvm_{key[:40]}.o")


def load_object(key):
    """The cached object code of ``key``, or None (no cache, no entry, unreadable or corrupt)."""
    path = _path(key)
    if path is None:
        return None
    try:
        with open(path, "rb") as fh:
            blob = fh.read()
    except OSError:
        return None
    head = len(_MAGIC) + 32
    if len(blob) <= head or not blob.startswith(_MAGIC):
        return None
    obj = blob[head:]
    return obj if hashlib.sha256(obj).digest() == blob[len(_MAGIC):head] else None


def store_object(key, obj):
    """Write the object code ``obj`` of ``key`` atomically (olado's one atomic writer: a
    temporary file beside the entry, then ``os.replace``); a failure to write is ignored (the
    cache is an optimization)."""
    from ...result import atomic_write_bytes   # noqa: PLC0415 - the one atomic writer
    path = _path(key)
    if path is None or not obj:
        return
    obj = bytes(obj)
    try:
        atomic_write_bytes(path, _MAGIC + hashlib.sha256(obj).digest() + obj)
    except OSError:
        pass
