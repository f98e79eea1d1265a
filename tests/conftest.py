"""Test-suite set-up: pytest puts this folder on sys.path (rootdir conftest, no __init__.py), so
every test imports the shared problems as ``from fixtures.toy_problems import Pendulum``."""

import os

# every call of a bound kernel checks that its argument types are those it was bound to
# (olado.linalg.codegen.KernelSet): the invariant the production path relies on, checked on every
# problem of the suite
os.environ.setdefault("OLADO_CHECK_KERNEL_TYPES", "1")
