"""Co-simulation master: FMUs bound to roles, wired by name, stepped at integer ticks.

See :mod:`cosim.master.system` for the timing semantics and :mod:`cosim.master.fmu`
for the FMI layer.
"""
from .binding import RoleBinding
from .fmu import FMUError, FMUSlave
from .roles import CONTRACTS, RoleContract, check_contract
from .system import ControllerError, Master, RunResult, System, SystemError_

__all__ = ["CONTRACTS", "ControllerError", "FMUError", "FMUSlave", "Master", "RoleBinding",
           "RoleContract", "RunResult", "System", "SystemError_", "check_contract"]
