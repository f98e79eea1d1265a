"""Test-suite set-up: pytest puts this folder on sys.path (rootdir conftest, no __init__.py), so
every test imports the shared problems as ``from fixtures.toy_problems import Pendulum``."""

import os
import signal

import pytest

# every call of a bound kernel checks that its argument types are those it was bound to
# (olado.linalg.codegen.KernelSet): the invariant the production path relies on, checked on every
# problem of the suite
os.environ.setdefault("OLADO_CHECK_KERNEL_TYPES", "1")


@pytest.fixture
def python_default_sigint():
    """Python's own SIGINT handler, whatever the test run started with (a background job of a
    non-interactive shell has SIGINT ignored: olado then leaves it ignored, by design); the
    interrupt tests use it (pytestmark)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)
