"""The FMI import layer: what the standard asks of an importer, below the master.

``me`` integrates Model Exchange FMUs across communication steps (events by the
standard), ``fmi1`` adapts FMI 1.0 FMUs to the FMI 2.0 calls the master makes,
``check`` tells an FMU that cannot run here (errors) from one that deviates from the
standard in ways an importer can tolerate (warnings), ``unpack`` extracts and loads an
FMU once per process and hash (released with its last holder).
"""
