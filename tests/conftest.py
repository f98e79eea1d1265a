"""Test-suite set-up: pytest puts this folder on sys.path (rootdir conftest, no __init__.py), so
every test imports the shared problems as ``from fixtures.toy_problems import Pendulum``."""
