"""The algorithms over recorded trial logs, outside any co-simulation:
:mod:`.estimation` (``cosim estimate`` / ``cosim identify``)."""
