"""``python -m olado`` is the ``olado`` command."""

from .cli import run

run()
