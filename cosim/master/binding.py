"""Role bindings: any exporter's FMU playing a role of the package.

An FMU from another tool rarely has the contract's names and units: its motor angle is
``motor.phi`` in degrees, its current input ``i_ref`` in mA, and many exporters write
no unit at all. A :class:`RoleBinding` says, per contract variable (``cosim roles``),

* ``map``: which FMU variable plays it (``theta -> motor.phi``; default: the same name);
  the role's *parameters* (:data:`ROLE_PARAMETERS`, ``cosim roles``: ``J``, ``b``,
  ``fc``, ``w0``... of a ball-screw unit) are mapped the same way (``J: inertia``), so
  the parameters a scenario, a case or a negative control sets and the true values a
  procedure reads (``System.parameter_values``) reach the FMU's own parameter;
* ``units``: the unit the FMU's values are in (``theta: deg``, ``J: g.cm2``). A unit of
  the contract's dimension is converted (scale and offset: mm -> m, deg -> rad, rpm ->
  rad/s, kN -> N, m/min -> m/s, mA -> A, degC -> K); a unit is looked up in the FMU's
  UnitDefinitions first (any unit it defines with a BaseUnit), else in the Modelica
  unit syntax (:mod:`cosim.fmubuild.units`); a variable without a unit in the FMU is
  accepted only with a declared unit, never silently; an FMU whose declared unit
  differs from the contract's is converted only when the binding names that unit (the
  binding states every conversion it makes).

A binding comes from a scenario's ``fmus:`` entry (``map:``/``units:``), a binding file
(``cosim run --binding FILE``: ``ROLE: {fmu: PATH, map: {...}, units: {...}}``,
:func:`load_binding_file`) or ``--map ROLE.NAME=FMU_NAME[:UNIT]``
(:func:`parse_map_option`); :func:`cli_bindings` merges them for the command line.

The system then sees the FMU through its binding (:class:`BoundSlave`): variables under
the contract's names and in the contract's units, so connections, controllers,
recordings, the recorded units and the reports all speak the contract. The values are
converted where the master reads and writes the FMU: in the FMU's Real get/set calls
(the per-tick calls of :meth:`BoundSlave.raw` and the slow paths ``get_value`` /
``set_value``, which start values and initialisation go through). Conversions are
the affine maps of :mod:`cosim.master.units`, the same as on connections.

Errors list every difference at once (unknown contract variables, variables the FMU
lacks, units missing, of another dimension or unknown), as the contract check does.
"""
from __future__ import annotations

import ctypes
import dataclasses
from typing import Mapping

from ..fmi.fmu import FMUError, FMUSlave, VarInfo, suggest
from .roles import RoleContract
from .units import affine, base_unit, dimension, norm

_SYNTAX = ("Modelica unit syntax, e.g. m, mm, deg, rad/s, rev/min, rpm, mA, N, kN, N.m, "
           "m/s2, m/min, degC")

#: ``coupling`` values of a binding (see :class:`RoleBinding`)
COUPLINGS = ("", "group", "step")

#: The parameters of a role (contract name -> parameter -> (unit, meaning)) that the
#: package's scenarios and procedures set or read by name: a binding maps them to an
#: FMU's own parameters (``map: {J: inertia}``) and converts their units. The values
#: are those of the package's FMU for the role (BallScrewUnit.mo).
ROLE_PARAMETERS: dict[str, dict[str, tuple[str, str]]] = {
    "ballscrew": {
        "J": ("kg.m2", "total inertia at the motor shaft (Table 1); the procedures' true J"),
        "b": ("N.m.s/rad", "viscous friction coefficient (Table 1); the true b"),
        "fc": ("N.m", "Coulomb friction torque (Table 1); the true fc"),
        "Kt": ("N.m/A", "motor torque constant (Table 1); the true Kt"),
        "fs": ("N.m", "static (breakaway) friction torque (a negative control raises it)"),
        "ws": ("rad/s", "Stribeck speed"),
        "sigma0": ("N.m/rad", "LuGre bristle stiffness"),
        "sigma1": ("N.m.s/rad", "LuGre bristle damping"),
        "wd": ("rad/s", "speed over which the bristle damping fades"),
        "lead": ("m", "ball-screw lead: nut travel per motor revolution"),
        "delta_enc": ("rad", "encoder resolution (a negative control coarsens it)"),
        "theta0": ("rad", "initial motor angle"),
        "w0": ("rad/s", "initial motor speed (free_motion starts in motion)"),
    },
}


def role_parameters(contract: RoleContract | None) -> dict[str, tuple[str, str]]:
    """The parameters a binding may map for ``contract`` (parameter -> (unit, meaning))."""
    return ROLE_PARAMETERS.get(getattr(contract, "name", None), {})


class BindingError(ValueError):
    """A role binding that is malformed (not a mapping of names to strings)."""


@dataclasses.dataclass(frozen=True)
class RoleBinding:
    """How an FMU plays a role: ``map`` contract variable or role parameter -> FMU
    variable, ``units`` the same names -> the unit of the FMU's values (both optional
    per name)."""
    map: Mapping[str, str] = dataclasses.field(default_factory=dict)
    units: Mapping[str, str] = dataclasses.field(default_factory=dict)
    #: how a scenario may solve this FMU when its role is in a coupled group
    #: (``system.coupled``, a stiff load cell or wall): ``""`` as the scenario says
    #: (Model Exchange in the group); ``"step"``: a Co-Simulation-only FMU leaves the
    #: group and its connections to it are exchanged at the master step (explicit;
    #: the accuracy this costs is in docs/bring-your-own-fmu.md). Not a view of the
    #: FMU: :class:`BoundSlave` ignores it, :mod:`cosim.scenarios.build` reads it.
    coupling: str = ""

    def __bool__(self) -> bool:
        return bool(self.map or self.units)

    def to_dict(self) -> dict:
        out = {k: dict(v) for k, v in (("map", self.map), ("units", self.units)) if v}
        if self.coupling:
            out["coupling"] = self.coupling
        return out

    @classmethod
    def from_spec(cls, spec, where: str = "binding") -> "RoleBinding":
        """From ``{"map": {...}, "units": {...}}`` (a scenario's ``fmus:`` entry or a
        binding file); errors name ``where`` and the field."""
        if spec is None:
            return cls()
        if isinstance(spec, RoleBinding):
            return spec
        if not isinstance(spec, Mapping):
            raise BindingError(f"{where}: a binding is a mapping with 'map' and/or 'units', "
                               f"got {type(spec).__name__}")
        extra = [k for k in spec if k not in ("map", "units", "coupling")]
        if extra:
            raise BindingError(f"{where}: unknown key(s) {extra} (a binding has 'map' and "
                               f"'units'; a role parameter is mapped in 'map' too, e.g. "
                               f"map: {{J: inertia}}, units: {{J: g.cm2}})")
        out = {}
        for key in ("map", "units"):
            d = spec.get(key) or {}
            if not isinstance(d, Mapping):
                raise BindingError(f"{where}.{key}: must be a mapping (contract variable -> "
                                   f"{'FMU variable' if key == 'map' else 'unit'}), got "
                                   f"{type(d).__name__} {d!r}")
            for k, v in d.items():
                if not isinstance(k, str) or not isinstance(v, str) or not v.strip():
                    raise BindingError(f"{where}.{key}.{k}: must be a non-empty string, got "
                                       f"{type(v).__name__} {v!r}")
            out[key] = {k: v.strip() for k, v in d.items()}
        coupling = spec.get("coupling") or ""
        if coupling not in COUPLINGS:
            raise BindingError(f"{where}.coupling: {coupling!r} is not one of "
                               f"{sorted(c for c in COUPLINGS if c)} (step: a "
                               f"Co-Simulation-only FMU exchanged with its coupled group at "
                               f"the master step)")
        return cls(out.get("map", {}), out.get("units", {}), coupling)

    def static_diffs(self, contract: RoleContract) -> list[tuple[str, str, str]]:
        """What is wrong with the binding whatever the FMU: (key, contract variable,
        message) for names that are not the contract's and declared units that are not
        units or not of the contract variable's dimension (a scenario checks these at
        load time, with the line)."""
        out = []
        params = role_parameters(contract)
        names = [n for n, *_ in contract.variables()] + list(params)
        other = _written_for(self, contract)
        if other is not None:
            # a binding of another role's FMU (a 1-DOF unit for a rig): one line, why
            return [("map", "", f"the binding is written for the {other.name!r} contract "
                     f"({other.description}), and this role plays the {contract.name!r} "
                     f"contract ({contract.description}): the FMU does not fit the role"
                     + (f"; {_SEPARATE[contract.name]}" if contract.name in _SEPARATE
                        else ""))]
        for key, table in (("map", self.map), ("units", self.units)):
            for cv in table:
                if contract.unit(cv) is None and cv not in params:
                    close = suggest(cv, names, 3)
                    out.append((key, cv, f"binding {key}: {cv!r} is not a variable or "
                                f"parameter of the {contract.name!r} contract" + (
                                    f" (did you mean {', '.join(map(repr, close))}?)" if close
                                    else f" ({', '.join(contract.inputs)} in; "
                                    f"{', '.join(contract.outputs)} out"
                                    + (f"; parameters {', '.join(params)}" if params else "")
                                    + ")")))
        for cv, unit in self.units.items():
            cunit = contract.unit(cv) or params.get(cv, (None,))[0]
            src = base_unit(unit)
            # a unit the syntax does not know may be one the FMU defines: checked when
            # the FMU is bound (BoundSlave), with its UnitDefinitions
            if cunit is not None and src is not None:
                msg = unit_problem(repr(cv), unit, src, cunit)
                if msg:
                    out.append(("units", cv, msg))
        return out

    def parameters(self, contract: RoleContract | None) -> dict[str, str]:
        """The mapped role parameters: role parameter -> FMU variable."""
        return {k: v for k, v in self.map.items()
                if contract is None or contract.unit(k) is None}

    def merged(self, other: "RoleBinding") -> "RoleBinding":
        """This binding with ``other``'s entries over it."""
        return RoleBinding({**self.map, **other.map}, {**self.units, **other.units},
                           other.coupling or self.coupling)


#: where a unit FMU takes part in a trial whose role here is a composite rig
_SEPARATE = {
    "zero_force_rig": "a unit FMU ('ballscrew') takes part in the zero-force trial as the "
                      "unit under test of scenarios/coupled/zero_force_separate.yaml "
                      "(--fmu unit=PATH or unit: in the binding file)",
    "wall_rig": "a unit FMU ('ballscrew') takes part in the bilateral trial as its master "
                "(role master here) or as the slave of "
                "scenarios/coupled/bilateral_separate.yaml (role slave)",
    "xy_table": "the circular and reaching trials need a 2-DOF table (a force command and "
                "a hand force per axis): one 1-DOF unit does not make one",
}


def _written_for(b: "RoleBinding", contract: RoleContract):
    """The other contract all of ``b``'s names belong to when none of a few of them is
    ``contract``'s, else None."""
    from .roles import CONTRACTS
    names = set(b.map) | set(b.units)
    mine = {n for n, *_ in contract.variables()} | set(role_parameters(contract))
    if len(names) < 3 or names & mine == names or len(names - mine) < len(names) / 2:
        return None
    for c in CONTRACTS.values():
        if c.name != contract.name and names <= ({n for n, *_ in c.variables()}
                                                 | set(role_parameters(c))):
            return c
    return None


def unit_problem(where: str, unit: str, src, cunit: str) -> str | None:
    """Why values in ``unit`` (its base ``src``, None if unknown) cannot play a contract
    variable in ``cunit``; None if they can."""
    if src is None:
        return f"{where}: unit {unit!r} is not defined by the FMU nor a unit of the {_SYNTAX}"
    dst = base_unit(cunit)
    if src.exponents != dst.exponents:
        return (f"{where}: unit {unit!r} ({dimension(src)}) is not of the dimension of the "
                f"role's {cunit!r} ({dimension(dst)})")
    return None


def parse_map_option(text: str) -> tuple[str, str, str, str | None]:
    """``ROLE.NAME=FMU_VAR[:UNIT]`` (``--map``; NAME a contract variable or a role
    parameter, ``plant.J=inertia:g.cm2``) -> (role, name, FMU variable, unit or None).
    An empty FMU_VAR keeps the contract's name (``master.theta=:deg`` declares a unit
    only)."""
    lhs, eq, rhs = str(text).partition("=")
    role, dot, cvar = lhs.strip().partition(".")
    if not eq or not dot or not role or not cvar:
        raise BindingError(f"--map {text!r}: expected ROLE.CONTRACT_VAR=FMU_VAR[:UNIT] "
                           f"(e.g. master.theta=motor.phi:deg)")
    fvar, colon, unit = rhs.strip().rpartition(":")
    if not colon:
        fvar, unit = rhs.strip(), ""
    fvar, unit = fvar.strip() or cvar, unit.strip()
    if colon and not unit:
        raise BindingError(f"--map {text!r}: empty unit after ':'")
    return role, cvar, fvar, unit or None


def load_binding_file(path) -> dict[str, tuple[str | None, "RoleBinding"]]:
    """A binding file (``cosim run --binding FILE``): role -> (its FMU's path or None,
    its binding). The file is YAML, per role ``{fmu: PATH, map: {...}, units: {...}}``;
    a relative ``fmu`` is relative to the file. Errors name the file, the role and the
    field (:class:`BindingError`)."""
    import yaml
    from pathlib import Path
    f = Path(path)
    try:
        doc = yaml.safe_load(f.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise BindingError(f"--binding {f}: {exc}") from None
    if not isinstance(doc, Mapping):
        raise BindingError(f"--binding {f}: expected a mapping role -> {{fmu: PATH, "
                           f"map: {{...}}, units: {{...}}}}")
    out = {}
    for role, spec in doc.items():
        if not isinstance(spec, Mapping):
            raise BindingError(f"--binding {f}: {role}: expected a mapping with fmu, map, "
                               f"units")
        spec = dict(spec)
        fmu = spec.pop("fmu", None)
        binding = RoleBinding.from_spec(spec, f"--binding {f}: {role}")
        if fmu is not None:
            if not isinstance(fmu, str) or not fmu.strip():
                raise BindingError(f"--binding {f}: {role}.fmu: expected a path, got {fmu!r}")
            p = Path(fmu) if Path(fmu).is_absolute() else f.parent / fmu
            if not p.is_file():
                raise BindingError(f"--binding {f}: {role}.fmu: FMU file {p} does not exist")
            fmu = str(p.resolve())
        out[str(role)] = (fmu, binding)
    return out


def cli_bindings(fmu_paths: Mapping[str, str], files=(), maps=()) \
        -> dict[str, tuple[str, "RoleBinding"]]:
    """The command line's swaps: role -> (FMU path, binding) from ``--fmu`` paths
    (``fmu_paths``, role -> path), ``--binding`` files and ``--map`` options (a --map
    entry over the files', a file's over an earlier file's; --fmu's path over a file's
    ``fmu``). A binding for a role without an FMU swapped in is refused."""
    paths = dict(fmu_paths)
    bindings: dict[str, RoleBinding] = {}
    for f in files or ():
        for role, (fmu, b) in load_binding_file(f).items():
            bindings[role] = bindings.get(role, RoleBinding()).merged(b)
            if fmu is not None and role not in paths:
                paths[role] = fmu
    for item in maps or ():
        role, name, fvar, unit = parse_map_option(item)
        b = RoleBinding({name: fvar} if fvar != name else {}, {name: unit} if unit else {})
        bindings[role] = bindings.get(role, RoleBinding()).merged(b)
    missing = sorted(set(bindings) - set(paths))
    if missing:
        raise BindingError(f"--map/--binding for role(s) {missing} without an FMU swapped in "
                           f"(--fmu ROLE=PATH, or fmu: in the binding file); a scenario's own "
                           f"FMU is bound in the scenario file (map:/units: in its fmus entry)")
    return {r: (p, bindings.get(r, RoleBinding())) for r, p in paths.items()}


class BoundSlave(FMUSlave):
    """An FMU seen through a :class:`RoleBinding`: the contract's variables under their
    contract names and units (the FMU's own names of bound variables are hidden; other
    variables keep theirs), values converted in every Real get/set.

    After construction, ``binding_diffs`` lists what does not fit (empty when the
    binding is complete) and ``binding_reported`` the contract variables those lines
    are about (the contract check skips them: one line per problem)."""

    def __init__(self, path, binding: RoleBinding, contract: RoleContract, role: str = "fmu",
                 kind: str = "auto", rtol: float = 1e-6):
        super().__init__(path, role=role, kind=kind, rtol=rtol)
        self.binding = binding
        self.contract = contract
        #: the FMU's variables as its modelDescription declares them
        self.fmu_variables: dict[str, VarInfo] = dict(self.variables)
        #: value reference -> (gain, offset, contract unit): contract = gain * FMU + offset
        self.conversions: dict[int, tuple[float, float, str]] = {}
        self.binding_diffs: list[str] = []
        self.binding_reported: set[str] = set()
        self._renamed: dict[str, str] = {}      # FMU name -> contract name
        self._bind()

    # ------------------------------------------------------------ the view
    def _bind(self):
        b, c, fv = self.binding, self.contract, self.fmu_variables
        diffs, reported = self.binding_diffs, self.binding_reported
        defs = self.md.unitDefinitions
        params = role_parameters(c)
        diffs += [m for _, cv, m in b.static_diffs(c) if c.unit(cv) is None
                  and cv not in params]
        bound: dict[str, VarInfo] = {}
        claims: dict[int, tuple[float, float]] = {}     # vr -> (gain, offset) of its binding
        for cv, kind, cunit, _ in c.variables():
            fname = b.map.get(cv, cv)
            v = fv.get(fname)
            if v is None:
                if cv in b.map:
                    close = suggest(fname, [n for n, x in fv.items() if x.causality == kind], 3)
                    diffs.append(f"{cv!r} [{cunit}] is bound to {fname!r}, which the FMU does "
                                 f"not have" + (f" (its {kind}s {', '.join(map(repr, close))})"
                                                if close else ""))
                    reported.add(cv)
                continue
            where = f"{cv!r}" + (f" (the FMU's {fname!r})" if fname != cv else "")
            declared, fu = b.units.get(cv), v.unit
            if fname != cv:
                self._renamed[fname] = cv
            if v.type != "Real":
                bound[cv] = dataclasses.replace(v, name=cv)
                continue        # the contract check says the type is wrong
            msg, src = _bound_unit(where, cv, declared, fu, cunit, defs, "its values")
            if msg:
                diffs.append(msg)
                reported.add(cv)
                continue
            dst = base_unit(cunit)
            if not declared and norm(fu) != norm(cunit):
                # a conversion the binding does not state: the contract check reports it
                # with the line to add
                bound[cv] = dataclasses.replace(v, name=cv)
                continue
            gain, offset = affine(src, dst)
            prev = claims.setdefault(v.vr, (gain, offset))
            if prev != (gain, offset):
                # one value read two ways (theta in rad, theta_enc in deg of one variable)
                diffs.append(f"{where}: the FMU's {fname!r} (value reference {v.vr}) is "
                             f"bound twice with different units")
                reported.add(cv)
                continue
            if (gain, offset) != (1.0, 0.0):
                if v.fmi_type not in ("Real", "Float64") or v.shape:
                    diffs.append(f"{where} is a {v.fmi_type}{' array' if v.shape else ''}: "
                                 f"the binding converts scalar Real/Float64 variables only")
                    reported.add(cv)
                    continue
                self.conversions[v.vr] = (gain, offset, cunit)
            start = v.start
            if start is not None and (gain, offset) != (1.0, 0.0):
                try:
                    start = repr(float(start) * gain + offset)
                except ValueError:
                    pass
            bound[cv] = dataclasses.replace(v, name=cv, unit=cunit, start=start)
        self._bind_parameters(bound, claims)
        view = {}
        for n, v in fv.items():
            if n in self._renamed or n in bound:
                continue
            # an alias of a converted variable (same value reference) reads converted
            conv = self.conversions[v.vr] if self._converted(v) else None
            view[n] = dataclasses.replace(v, unit=conv[2]) if conv else v
        view.update(bound)
        self.variables = view

    def _bind_parameters(self, bound: dict, claims: dict):
        """The role parameters the binding maps (``J: inertia``): renamed, and converted
        from the FMU's unit to the role's (:data:`ROLE_PARAMETERS`) like a variable."""
        b, c, fv = self.binding, self.contract, self.fmu_variables
        diffs, reported, defs = self.binding_diffs, self.binding_reported, \
            self.md.unitDefinitions
        params = role_parameters(c)
        for cp, fname in b.parameters(c).items():
            if cp not in params:
                continue                    # static_diffs said it is no parameter
            cunit = params[cp][0]
            v = fv.get(fname)
            if v is None:
                close = suggest(fname, [n for n, x in fv.items()
                                        if x.causality in ("parameter", "input")], 3)
                diffs.append(f"parameter {cp!r} [{cunit}] is bound to {fname!r}, which the "
                             f"FMU does not have" + (f" (its parameters "
                                                     f"{', '.join(map(repr, close))})"
                                                     if close else ""))
                reported.add(cp)
                continue
            where = f"parameter {cp!r} (the FMU's {fname!r})"
            self._renamed[fname] = cp
            if v.type != "Real" or v.shape:
                diffs.append(f"{where} is a {v.fmi_type or v.type}"
                             f"{' array' if v.shape else ''}: a role parameter binds a "
                             f"scalar Real")
                reported.add(cp)
                continue
            declared, fu = b.units.get(cp), v.unit
            msg, src = _bound_unit(where, cp, declared, fu, cunit, defs, "its value")
            if msg:
                diffs.append(msg)
                reported.add(cp)
                continue
            if not declared and norm(fu) != norm(cunit):
                # as for a variable: the binding states every conversion it makes
                diffs.append(f"{where} is in {fu!r} (the FMU's unit), the role's in "
                             f"{cunit!r}: the binding converts it with units: {{{cp}: {fu}}}")
                reported.add(cp)
                continue
            gain, offset = affine(src, base_unit(cunit))
            if claims.setdefault(v.vr, (gain, offset)) != (gain, offset):
                diffs.append(f"{where}: the FMU's {fname!r} (value reference {v.vr}) is "
                             f"bound twice with different units")
                reported.add(cp)
                continue
            if (gain, offset) != (1.0, 0.0):
                self.conversions[v.vr] = (gain, offset, cunit)
            start = v.start
            if start is not None and (gain, offset) != (1.0, 0.0):
                try:
                    start = repr(float(start) * gain + offset)
                except ValueError:
                    pass
            bound[cp] = dataclasses.replace(v, name=cp, unit=cunit, start=start)

    def var(self, name: str) -> VarInfo:
        if name not in self.variables and name in self._renamed:
            raise FMUError(f"role {self.role}: {self.path.name}'s {name!r} plays the role's "
                           f"{self._renamed[name]!r} (binding): use {self._renamed[name]!r}")
        return super().var(name)

    def describe_binding(self) -> list[str]:
        """One line per bound contract variable: name, FMU variable, conversion."""
        out = []
        for cv, _, cunit, _ in self.contract.variables():
            v = self.variables.get(cv)
            if v is None:
                continue
            fname = self.binding.map.get(cv, cv)
            g, o, _ = self.conversions.get(v.vr, (1.0, 0.0, cunit))
            unit = self.binding.units.get(cv) or self.fmu_variables[fname].unit
            conv = "" if (g, o) == (1.0, 0.0) else \
                f" ({cunit} = {g:.10g} x {unit}" + (f" + {o:.10g}" if o else "") + ")"
            out.append(f"{cv} <- {fname} [{unit}]{conv}")
        params = role_parameters(self.contract)
        for cp, fname in self.binding.parameters(self.contract).items():
            v = self.variables.get(cp)
            if v is None or cp not in params:
                continue
            cunit = params[cp][0]
            g, o, _ = self.conversions.get(v.vr, (1.0, 0.0, cunit))
            unit = self.binding.units.get(cp) or self.fmu_variables[fname].unit
            conv = "" if (g, o) == (1.0, 0.0) else \
                f" ({cunit} = {g:.10g} x {unit}" + (f" + {o:.10g}" if o else "") + ")"
            out.append(f"parameter {cp} <- {fname} [{unit}]{conv}")
        if self.binding.coupling == "step":
            out.append("coupling: step (Co-Simulation; exchanged with its coupled group at "
                       "the master step, not solved in it)")
        return out

    # ------------------------------------------------------------ conversions
    def _converted(self, v: VarInfo) -> tuple[float, float] | None:
        if v.type != "Real" or (self.fmi3 and v.fmi_type != "Float64"):
            return None
        c = self.conversions.get(v.vr)
        return None if c is None else c[:2]

    def get_value(self, v: VarInfo) -> list:
        out = super().get_value(v)
        c = self._converted(v)
        return [x * c[0] + c[1] for x in out] if c else out

    def set_value(self, v: VarInfo, value):
        c = self._converted(v)
        if c is not None and not isinstance(value, str):
            try:
                value = (float(value) - c[1]) / c[0]
            except (TypeError, ValueError):
                pass        # the FMU's setter says what is wrong with it
        super().set_value(v, value)

    def raw(self):
        """The per-tick calls (:meth:`FMUSlave.raw`), the Real get/set converting the
        bound variables: a read is converted in the caller's buffer after the FMU's
        call, a write from a copy (the caller's buffer keeps the contract's units)."""
        io = super().raw()
        if not self.conversions:
            return io
        io.get = _converting_get(io.get, self.conversions)
        io.set = _converting_set(io.set, self.conversions)
        return io


def _count(n) -> int:
    return int(getattr(n, "value", n))


def _converting_get(get, conv):
    plans: dict = {}     # id(vr array) -> (the array, [(index, gain, offset)])

    def get_converted(comp, vr, n, buf, *rest):
        st = get(comp, vr, n, buf, *rest)
        plan = plans.get(id(vr))
        if plan is None or plan[0] is not vr:
            plan = plans[id(vr)] = (vr, [(i, *conv[vr[i]][:2]) for i in range(_count(n))
                                         if vr[i] in conv])
        for i, g, o in plan[1]:
            buf[i] = buf[i] * g + o
        return st
    return get_converted


def _converting_set(set_, conv):
    plans: dict = {}     # id(vr array) -> (the array, [(index, gain, offset)], buffer)

    def set_converted(comp, vr, n, buf, *rest):
        plan = plans.get(id(vr))
        if plan is None or plan[0] is not vr:
            m = _count(n)
            plan = plans[id(vr)] = (vr, [(i, *conv[vr[i]][:2]) for i in range(m)
                                         if vr[i] in conv], (ctypes.c_double * max(m, 1))(), m)
        if not plan[1]:
            return set_(comp, vr, n, buf, *rest)
        tmp = plan[2]
        ctypes.memmove(tmp, buf, 8 * plan[3])
        for i, g, o in plan[1]:
            tmp[i] = (tmp[i] - o) / g
        return set_(comp, vr, n, tmp, *rest)
    return set_converted


def _bound_unit(where: str, name: str, declared: str | None, fu: str | None, cunit: str,
                defs, what: str) -> tuple[str | None, object]:
    """The unit a bound variable or parameter's values are in: ``(problem, base unit)``.

    ``declared`` is the binding's unit, ``fu`` the FMU's, ``cunit`` the role's; a unit
    the FMU defines (``defs``) is read through its definition, any other by its syntax.
    ``problem`` is the message when the values' unit is missing, contradicts the FMU's,
    or does not convert to the role's; ``what`` says what the unit is of."""
    unit = declared or fu
    if not unit:
        verb = "they are" if what.endswith("values") else "it is"
        return (f"{where} has no unit in the FMU and the binding declares none: declare the "
                f"unit of {what}, units: {{{name}: {cunit}}} if {verb} in {cunit}"), None
    if declared and fu and norm(declared) != norm(fu):
        a, d = base_unit(fu, defs), base_unit(declared, defs)
        if a is not None and d is not None and a != d:
            return (f"{where}: the binding declares unit {declared!r}, the FMU declares "
                    f"{fu!r}"), None
    src = base_unit(unit, defs)
    msg = unit_problem(where, unit, src, cunit)
    if msg and src is None and not declared:      # the FMU's own, unknown unit string
        msg += f" (declare what it means: units: {{{name}: ...}})"
    return msg, src
