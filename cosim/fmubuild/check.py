"""Moved to :mod:`cosim.fmi.check` (the FMI layer); kept for existing imports."""
from ..fmi.check import (MAX_UNCOMPRESSED, SUPPORTED, CheckReport, FMUCheckError,  # noqa: F401
                         check_fmu, fmi_version, format_report, model_warnings, safe_extract,
                         safe_members)
