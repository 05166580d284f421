"""Re-render the HTML pages of a finished ``cosim suite`` (or ``cosim run``) folder
from what is stored there (summary.json, each scenario's verdict.json and runs);
nothing is rerun::

    python -m cosim.report DIR          # DIR from `cosim suite ... --out DIR`
"""
from __future__ import annotations

import sys

from .render import main

if __name__ == "__main__":
    sys.exit(main())
