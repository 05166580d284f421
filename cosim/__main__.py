"""``python -m cosim``: the ``cosim`` command."""
import sys

from .cli import main

sys.exit(main())
