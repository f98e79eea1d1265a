"""``python -m olado`` is the ``olado`` command."""

import sys

from .cli import main

sys.exit(main())
