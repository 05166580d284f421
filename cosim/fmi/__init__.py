"""The FMI import layer: what the standard asks of an importer, below the master.

``unpack`` extracts each FMU once per process and FMU hash and tracks the shared
library handles its users open, so nothing is left mapped or on disk afterwards.
"""
