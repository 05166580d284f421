"""``python -m cosim.cli``: the ``cosim`` command."""
import sys

from . import main

sys.exit(main())
