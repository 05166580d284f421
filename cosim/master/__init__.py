"""Co-simulation master: FMUs bound to roles, wired by name, stepped at integer ticks.

See :mod:`cosim.master.system` for the timing semantics; the FMUs themselves (loading,
calls, error text, :class:`~cosim.fmi.fmu.FMUError`) are :mod:`cosim.fmi.fmu`'s.
"""
from .binding import RoleBinding
from .roles import CONTRACTS, RoleContract, check_contract
from .system import ControllerError, Master, RunResult, System, SystemError_

__all__ = ["CONTRACTS", "ControllerError", "Master", "RoleBinding",
           "RoleContract", "RunResult", "System", "SystemError_", "check_contract"]
