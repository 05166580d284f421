"""Fast forms of readable references in :mod:`cosim.algorithms` (tested equal to them)."""
