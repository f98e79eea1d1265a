"""The code-generation version is part of the signature of every kernel compiled for the sizes
(olado.linalg.codegen.KERNEL_VERSION), so numba's on-disk caches of those kernels are not loaded
again after a change of the generator: a new version is a new signature, compiled afresh."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numba

from olado.linalg import codegen

ROOT = Path(__file__).resolve().parents[2]


def test_the_version_is_part_of_the_size_tags_type(monkeypatch):
    tags = codegen.size_tags(2, 3)
    assert [len(t) for t in tags] == [2, 3, 5, codegen.KERNEL_VERSION]
    monkeypatch.setattr(codegen, "KERNEL_VERSION", codegen.KERNEL_VERSION + 1)
    newer = codegen.size_tags(2, 3)
    assert numba.typeof(newer) != numba.typeof(tags)
    assert len(tags) == len(codegen.SizeTags._fields)


# one run: factorize a 1 x 1 block problem with the given kernel version, print the cache
# statistics of the kernel (numba's cache in the directory NUMBA_CACHE_DIR)
_RUN = textwrap.dedent("""
    import sys
    import numpy as np
    from olado.linalg import codegen, riccati_fixed as rf
    from olado.linalg.riccati_kernels import Costs, Dynamics, IPTerms, PlainFactors
    codegen.KERNEL_VERSION = int(sys.argv[1])
    N = 3
    z = np.zeros
    costs = tuple(Costs(Q=np.ones((N + 1, 1, 1)), S=z((N, 1, 1)), R=np.ones((N, 1, 1))))
    dyn = tuple(Dynamics(A=np.ones((N, 1, 1)), B=np.ones((N, 1, 1))))
    ipt = tuple(IPTerms(Dx=z((N + 1, 1)), Du=z((N, 1)), Ci=z((N, 0, 2)), sig=z((N, 0)), ni=z(N, np.int64)))
    fac = tuple(PlainFactors(P=np.empty((N + 1, 1, 1)), K=np.empty((N, 1, 1)), L=np.empty((N, 1, 1))))
    assert rf._factor_unconstrained_fixed(codegen.size_tags(1, 1), costs, dyn, ipt, 0.0, fac) == -1
    stats = rf._factor_unconstrained_fixed.stats
    print(len(stats.cache_hits), len(stats.cache_misses))
""")


def test_a_new_version_is_compiled_afresh_instead_of_loaded_from_the_disk_cache(tmp_path):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path), PYTHONPATH=str(ROOT))

    def run(version):
        out = subprocess.run([sys.executable, "-c", _RUN, str(version)], env=env, cwd=ROOT, check=True,
                             capture_output=True, text=True).stdout.split()
        return tuple(int(v) for v in out)       # (cache hits, cache misses)

    v = codegen.KERNEL_VERSION
    assert run(v) == (0, 1)          # compiled and saved
    assert run(v) == (1, 0)          # loaded from the disk cache
    assert run(v + 1) == (0, 1)      # same source files, new version: compiled, not loaded
    assert run(v) == (1, 0)          # the entry of the old version is still there
