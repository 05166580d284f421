"""A co-simulated system, and the master that runs it at a fixed step.

The master knows no algorithm. A :class:`System` binds roles to FMUs, connects FMU
variables, plugs in controllers (any :class:`~cosim.algorithms.base.DiscreteBlock`)
with their wiring by name, and stimuli (functions of time). Names are
``role.variable`` for FMU variables, ``ctrl.output`` for controller outputs and
``stim.name`` for stimuli.

One tick k (t_k = k * Ts, k an integer):

1. read every FMU output used by anything (values at t_k);
2. evaluate stimuli at t_k; step the controllers in the order they were added, each
   with the measurements of tick k (FMU outputs, stimuli, and outputs of
   controllers added before it in this tick);
3. record; set every FMU input (connections, controller outputs, stimuli);
4. doStep every FMU from t_k to t_k + Ts (Jacobi: all see inputs of tick k).
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Callable, Mapping

import numpy as np

from .fmu import FMUError, FMUSlave
from .roles import CONTRACTS, RoleContract, check_contract


class SystemError_(ValueError):
    """A system description that cannot run (unknown name, mismatched contract)."""


@dataclasses.dataclass
class _Controller:
    name: str
    block: object
    wiring: dict       # block input -> source name
    record: tuple = ()


class System:
    """Roles, connections, controllers and stimuli of one co-simulation."""

    def __init__(self, step_size: float = 1e-3):
        if not step_size > 0:
            raise SystemError_(f"step size must be > 0, got {step_size}")
        self.Ts = float(step_size)
        self.roles: dict[str, FMUSlave] = {}
        self.params: dict[str, dict] = {}
        self.connections: list[tuple[str, str]] = []      # (source, "role.input")
        self.controllers: list[_Controller] = []
        self.stimuli: dict[str, Callable[[float], float]] = {}

    # ----------------------------------------------------------- building
    def add_fmu(self, role: str, path, contract: str | RoleContract | None = None,
                parameters: Mapping[str, float] | None = None, kind: str = "auto") -> FMUSlave:
        if role in self.roles:
            raise SystemError_(f"role {role!r} is bound twice")
        if "." in role:
            raise SystemError_(f"role name {role!r} must not contain '.'")
        slave = FMUSlave(path, role=role, kind=kind)
        if contract is not None:
            c = CONTRACTS[contract] if isinstance(contract, str) else contract
            diffs = check_contract(slave, c)
            if diffs:
                raise SystemError_(f"role {role!r}: {Path(path).name} does not fit the "
                                   f"{c.name!r} contract:\n  - " + "\n  - ".join(diffs))
        for name in (parameters or {}):
            slave.var(name)
        self.roles[role] = slave
        self.params[role] = dict(parameters or {})
        return slave

    def set_parameters(self, role: str, **values):
        slave = self._role(role)
        for name in values:
            slave.var(name)
        self.params[role].update(values)

    def connect(self, source: str, dest: str):
        """Drive FMU input ``dest`` ('role.var') from ``source`` (any name)."""
        self._fmu_var(dest, causality="input")
        self.connections.append((source, dest))

    def add_stimulus(self, name: str, fn: Callable[[float], float]):
        self.stimuli[name] = fn

    def add_controller(self, name: str, block, wiring: Mapping[str, str],
                       outputs: Mapping[str, str] | None = None, record: tuple = ()):
        """Plug a DiscreteBlock in. ``wiring``: block input -> source name;
        ``outputs``: block output -> FMU input ('role.var') it drives."""
        if name in self.roles or name in [c.name for c in self.controllers] or name == "stim":
            raise SystemError_(f"name {name!r} already used")
        missing = [i for i in getattr(block, "inputs", ()) if i not in wiring]
        optional = set(getattr(block, "optional_inputs", ()))
        missing = [m for m in missing if m not in optional]
        if missing:
            raise SystemError_(f"controller {name!r}: inputs not wired: {missing}")
        self.controllers.append(_Controller(name, block, dict(wiring), tuple(record)))
        for out, dest in (outputs or {}).items():
            if out not in getattr(block, "outputs", (out,)):
                raise SystemError_(f"controller {name!r} has no output {out!r} "
                                   f"(it has {list(block.outputs)})")
            self.connect(f"{name}.{out}", dest)

    # ----------------------------------------------------------- helpers
    def _role(self, role: str) -> FMUSlave:
        try:
            return self.roles[role]
        except KeyError:
            raise SystemError_(f"unknown role {role!r} (roles: {sorted(self.roles)})") from None

    def _fmu_var(self, name: str, causality: str | None = None):
        role, _, var = name.partition(".")
        slave = self._role(role)
        try:
            v = slave.var(var)
        except FMUError as exc:
            raise SystemError_(str(exc)) from None
        if causality and v.causality != causality:
            raise SystemError_(f"{name} has causality {v.causality}, expected {causality}")
        return slave, v

    def provenance(self) -> list[dict]:
        return [dict(role=r, **dataclasses.asdict(s.info)) for r, s in self.roles.items()]


class Recorder:
    """Preallocated labelled arrays, ``time`` first."""

    def __init__(self, names: list[str], n: int):
        self.names = ["time"] + list(names)
        self.data = np.full((n, len(self.names)), np.nan)
        self.n = 0

    def as_dict(self) -> dict[str, np.ndarray]:
        return {k: self.data[: self.n, i].copy() for i, k in enumerate(self.names)}

    def to_pandas(self):
        import pandas as pd
        return pd.DataFrame(self.as_dict())

    def to_parquet(self, path):
        self.to_pandas().to_parquet(path, index=False)


@dataclasses.dataclass
class RunResult:
    signals: dict
    provenance: list
    completed: bool
    error: str | None = None
    ticks: int = 0

    def to_pandas(self):
        import pandas as pd
        return pd.DataFrame(self.signals)


class Master:
    """Runs a System for a duration at its fixed step."""

    def __init__(self, system: System, record: list[str] | None = None):
        self.system = system
        self.record = list(record or [])

    def run(self, duration: float, raise_on_error: bool = True) -> RunResult:
        sys_ = self.system
        Ts = sys_.Ts
        n_ticks = int(round(duration / Ts))
        if n_ticks <= 0:
            raise SystemError_(f"duration {duration} s is shorter than one step {Ts} s")

        # -- resolve every name once: values live in one float vector `val`
        names: dict[str, int] = {}

        def slot(name: str) -> int:
            if name not in names:
                names[name] = len(names)
            return names[name]

        fmu_reads: dict[str, list[str]] = {r: [] for r in sys_.roles}
        ctrl_names = {c.name for c in sys_.controllers}

        def source(name: str) -> int:
            head, _, tail = name.partition(".")
            if head == "stim":
                if tail not in sys_.stimuli:
                    raise SystemError_(f"unknown stimulus {name!r} (stimuli: {sorted(sys_.stimuli)})")
            elif head in ctrl_names:
                blk = next(c.block for c in sys_.controllers if c.name == head)
                if tail not in blk.outputs and not hasattr(blk, tail):
                    raise SystemError_(f"controller {head!r} has no output or attribute {tail!r}")
            elif head in sys_.roles:
                slave, v = sys_._fmu_var(name)
                if v.type != "Real":
                    raise SystemError_(f"{name} is {v.type}; only Real signals can be wired")
                if tail not in fmu_reads[head]:
                    fmu_reads[head].append(tail)
            else:
                raise SystemError_(f"unknown signal {name!r}: not a role, controller or stim.*")
            return slot(name)

        for src, _ in sys_.connections:
            source(src)
        for c in sys_.controllers:
            for src in c.wiring.values():
                source(src)
            for out in c.block.outputs:
                slot(f"{c.name}.{out}")
        rec_names = []
        for r in self.record:
            source(r) if r.partition(".")[0] != "" else None
            rec_names.append(r)

        # controller attribute recording (innovations, gains): names ctrl.attr not outputs
        attr_rec = [(names[r], r.partition(".")[0], r.partition(".")[2]) for r in rec_names
                    if r.partition(".")[0] in ctrl_names and
                    r.partition(".")[2] not in next(c.block for c in sys_.controllers
                                                    if c.name == r.partition(".")[0]).outputs]

        val = np.zeros(len(names))
        stim = [(names[f"stim.{k}"], fn) for k, fn in sys_.stimuli.items() if f"stim.{k}" in names]
        readers = []
        writers = []
        steppers = []
        try:
            for role, slave in sys_.roles.items():
                slave.instantiate(sys_.params.get(role), start_time=0.0)
            # initial inputs: connections from stimuli at t=0 so initialisation sees them
            for role, slave in sys_.roles.items():
                slave.exit_initialization()
            for role, slave in sys_.roles.items():
                rd = fmu_reads[role]
                readers.append((slave.real_reader(rd),
                                np.array([names[f"{role}.{v}"] for v in rd], dtype=int), role))
                ins = [(d.partition(".")[2], names[s]) for s, d in sys_.connections
                       if d.partition(".")[0] == role]
                writers.append((slave.real_writer([i for i, _ in ins]),
                                np.array([s for _, s in ins], dtype=int), role))
                steppers.append((slave.stepper(), role))
        except (FMUError, SystemError_):
            for s in sys_.roles.values():
                s.terminate()
            raise
        except Exception as exc:
            for s in sys_.roles.values():
                s.terminate()
            raise FMUError(f"initialisation failed: {exc}") from None

        ctrls = []
        for c in sys_.controllers:
            c.block.reset()
            ctrls.append((c.block.step, [(k, names[s]) for k, s in c.wiring.items()],
                          [(o, names[f"{c.name}.{o}"]) for o in c.block.outputs], c.name))
        ctrl_block = {c.name: c.block for c in sys_.controllers}
        rec = Recorder(rec_names, n_ticks + 1)
        rec_idx = np.array([names[r] for r in rec_names], dtype=int)

        error = None
        k = 0
        try:
            for k in range(n_ticks + 1):
                t = k * Ts
                for read, idx, role in readers:
                    if idx.size:
                        v = read()
                        if not np.all(np.isfinite(v)):
                            bad = [n for n, x in zip(fmu_reads[role], v) if not math.isfinite(x)]
                            raise FMUError(f"role {role}: non-finite output(s) {bad} at t = {t:.6f} s")
                        val[idx] = v
                for i, fn in stim:
                    val[i] = fn(t)
                for step, win, wout, cname in ctrls:
                    out = step({key: val[i] for key, i in win})
                    for o, i in wout:
                        x = out[o]
                        if not math.isfinite(x):
                            raise FMUError(f"controller {cname}: output {o} = {x} at t = {t:.6f} s")
                        val[i] = x
                for i, cname, attr in attr_rec:
                    val[i] = float(getattr(ctrl_block[cname], attr))
                row = rec.data[k]
                row[0] = t
                row[1:] = val[rec_idx]
                rec.n = k + 1
                if k == n_ticks:
                    break
                for write, idx, role in writers:
                    if idx.size:
                        write(val[idx])
                for step, role in steppers:
                    try:
                        step(t, Ts)
                    except FMUError:
                        raise
                    except Exception as exc:
                        raise FMUError(f"role {role}: doStep failed at t = {t:.6f} s: {exc}") from None
        except FMUError as exc:
            error = str(exc)
        finally:
            for s in sys_.roles.values():
                s.terminate()
        result = RunResult(rec.as_dict(), sys_.provenance(), error is None, error, rec.n)
        if error and raise_on_error:
            err = FMUError(error)
            err.result = result          # nothing recorded is lost
            raise err
        return result
