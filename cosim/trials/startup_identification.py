"""Start-up identification phase: the thesis chain RLS -> J, b, fc -> DOB/RFOB (Sec. 2.3, 2.5.3).

The thesis identifies each unit at the start of a session (Sec. 2.3, 2.5.2: ~10 s of
band-limited white-noise current, RLS on the current and the aaKF speed) and builds
its disturbance observer and reaction force observer (Sec. 2.1.2, eq. 5-10) from the
identified J, b, fc; the torque constant stays the datasheet's (the RLS identifies
J/Kt, b/Kt, fc/Kt from the current, so J, b, fc come out in units of the nominal Kt).

Procedure ``startup_identification`` (one run = two phases, in this order):

1. ``identification``: the scenario's own plant FMUs are built again with every
   controller, stimulus and connection of the trial removed, the couplings named in
   the file set to zero (``fmu_parameters``: the zero-force rig's load cell
   ``k_cell = d_cell = 0`` so the partner is out of the way; the bilateral slave's wall
   moved out of reach; the human FMU is not built: the operator does not hold the
   master during the start-up) and each unit excited by its own band-limited
   white-noise current (plus an optional weak position hold) for ``duration_s``.
   Each unit's encoder and accelerometer (its accelerometer FMU on a sequential
   connection, as in ``scenarios/identification.yaml``) feed an aaKF (default: the
   package's sigma_a bank, ``AakfParams()``; ``aakf`` sets the thesis's single
   filter instead); after the co-simulation the RLS
   (:func:`cosim.trials.identification.rls_history`, default: the package's integral
   regression, an extension of eq. 44; ``rls: {regression: eq44}`` gives the
   thesis's; aaKF speed, nominal Kt) runs over the record.
2. ``main``: the trial as the file describes it, with the DOB/RFOB controllers listed
   for each unit built from the identified values: DOB ``Jn_kg_m2 = J_id``,
   ``Ktn_Nm_per_A = Kt_n``; RFOB ``J_kg_m2 = J_id``, ``b_Nms_per_rad = b_id``,
   ``fc_Nm = fc_id``, ``Kt_Nm_per_A = Kt_n``. The identified values REPLACE whatever
   the file gives these fields (the chain is the point); a negative control degrades
   them with ``observer_scale`` (per controller, factor on J, b, fc, Kt), never by
   writing true values. ``main`` is stored first, so run metrics and case ratios read
   the trial (phase ``main``).

Why drive the rig's own unit rather than an identical unit FMU: the unit under test
of the zero-force rig and the bilateral slave live inside composite FMUs
(``ZeroForceRig``, ``WallUnitRig``); a separate BallScrewUnit "with the same
parameters" would identify the parameters we copy into it, not the device the
observers run on (a case, sweep or Monte-Carlo draw of ``J_u`` would silently not
reach the identification). Removing the coupling inside the rig identifies exactly
the unit the main phase runs. (With the unit as its own FMU in a coupled group,
``scenarios/coupled/zero_force_separate.yaml``, the identification builds that FMU alone.)

Values stored per run (``run.json`` -> the report's run table and the
"observer parameters" figure), for each unit ``u`` and parameter ``p`` in J, b, fc:
``{p}_id_{u}`` (identified), ``{p}_true_{u}`` (the FMU's value), ``{p}_err_pct_{u}``;
``Kt_n_{u}``, ``Kt_true_{u}``; ``id_travel_mm_{u}`` (largest excursion of the handle
during the excitation); and for every observer ``c`` actually built in the main phase
the parameters read back from the block: ``obs_{c}_J``, ``obs_{c}_Kt`` and for an RFOB
``obs_{c}_b``, ``obs_{c}_fc``. Artifacts: ``startup_identification`` (the same as a
table, plus the source, ``identified`` or ``true``).

Parameters (``parameters.startup_identification`` of the scenario)::

    duration_s: 10.0              # excitation length [s] (Sec. 2.5.2: ~10 s)
    excitation: {rms: 0.15, cutoff_hz: 50.0}   # band_limited_noise params, per unit stream
    hold_N_per_m: 0.0             # weak P hold on the encoder position (equivalent handle
                                  # stiffness [N/m]); 0: none
    Kt_nominal_Nm_per_A: (Table 1: devices.ballscrew.KT_NM_PER_A); also the RLS's Kt
    lead_m: 0.01                  # Table 1 (for the hold)
    aakf: {}                      # aaKF params of the identification phase
    rls: {}                       # RLSParams overrides (default: integral regression,
                                  # the extension; {regression: eq44}: the thesis's)
    source: identified            # or "true": the observers get the FMU's true values
                                  # (the former set-up, kept for comparison only)
    observer_scale: {}            # controller -> {J, b, fc, Kt: factor} (negative controls)
    units:
      <name>:
        role: rig                 # FMU role holding the unit
        current: i                # its current input
        encoder: theta_enc        # its encoder output [rad]
        acceleration: a           # its nut acceleration output (into the accelerometer)
        accelerometer: acc        # the accelerometer role of this unit
        fmu_parameters: {}        # set on this role during the identification only
        true_parameters: {J: J, b: b, fc: fc, Kt: Kt}   # FMU parameter names (report)
        dob: [dob]                # DOB controllers built from this unit's values
        rfob: [rfob]              # RFOB controllers built from this unit's values
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cosim.devices.ballscrew import KT_NM_PER_A
from cosim.scenarios.registry import ProcedureResult, controller, procedure
from cosim.trials.identification import fmu_values

PARAMS = ("J", "b", "fc")
DEFAULTS = {"duration_s": 10.0, "excitation": {"rms": 0.15, "cutoff_hz": 50.0},
            "hold_N_per_m": 0.0, "Kt_nominal_Nm_per_A": KT_NM_PER_A, "lead_m": 0.01,
            "aakf": {}, "rls": {}, "source": "identified", "observer_scale": {}}
UNIT_DEFAULTS = {"current": "i", "encoder": "theta_enc", "acceleration": "a",
                 "fmu_parameters": {}, "true_parameters": {"J": "J", "b": "b", "fc": "fc",
                                                           "Kt": "Kt"},
                 "dob": [], "rfob": []}
UNIT_KEYS = set(UNIT_DEFAULTS) | {"role", "accelerometer"}


# =========================================================================== exciter
@dataclass(frozen=True)
class ExcitationHoldParams:
    """Current of the start-up identification: the excitation (input ``i_exc``, a
    band-limited white-noise stimulus) minus a weak proportional hold on the encoder
    angle, ``i_cmd = i_exc - Kp_A_per_rad (theta_enc - theta_0)`` (theta_0: the first
    reading)."""
    Kp_A_per_rad: float = 0.0


@controller("excitation_hold", params=ExcitationHoldParams)
def _excitation_hold(params, ctx):
    """Band-limited white-noise current plus a weak position hold (identification)."""
    return ExcitationHold(ExcitationHoldParams(**params))


class ExcitationHold:
    inputs = ("i_exc", "theta_enc")
    outputs = ("i_cmd",)

    def __init__(self, p: ExcitationHoldParams):
        self.p = p
        self.reset()

    def reset(self):
        self._th0 = None

    def step(self, m):
        th = float(m["theta_enc"])
        if self._th0 is None:
            self._th0 = th
        return {"i_cmd": float(m["i_exc"]) - self.p.Kp_A_per_rad * (th - self._th0)}


# =========================================================================== config
def config(parameters: dict) -> dict:
    """The ``startup_identification`` parameters with defaults, checked."""
    raw = dict((parameters or {}).get("startup_identification") or {})
    unknown = set(raw) - set(DEFAULTS) - {"units"}
    if unknown:
        raise ValueError(f"startup_identification: unknown key(s) {sorted(unknown)} "
                         f"(keys: {sorted(DEFAULTS) + ['units']})")
    cfg = {**DEFAULTS, **raw}
    if cfg["source"] not in ("identified", "true"):
        raise ValueError(f"startup_identification.source must be 'identified' or 'true', "
                         f"got {cfg['source']!r}")
    units = raw.get("units") or {}
    if not units:
        raise ValueError("startup_identification.units: no unit to identify")
    cfg["units"] = {}
    for name, u in units.items():
        bad = set(u) - UNIT_KEYS
        if bad or "role" not in u or "accelerometer" not in u:
            raise ValueError(f"startup_identification.units.{name}: needs role and "
                             f"accelerometer; unknown key(s) {sorted(bad)}")
        cfg["units"][name] = {**UNIT_DEFAULTS, **u,
                              "true_parameters": {**UNIT_DEFAULTS["true_parameters"],
                                                  **(u.get("true_parameters") or {})}}
    observers = {c for u in cfg["units"].values() for c in list(u["dob"]) + list(u["rfob"])}
    for c, sc in (cfg["observer_scale"] or {}).items():
        if c not in observers:
            raise ValueError(f"startup_identification.observer_scale: {c!r} is not a DOB/RFOB "
                             f"of a unit (observers: {sorted(observers)})")
        if set(sc) - {"J", "b", "fc", "Kt"}:
            raise ValueError(f"startup_identification.observer_scale.{c}: keys are J, b, fc, Kt")
    return cfg


def identification_overrides(names: dict, cfg: dict) -> dict:
    """Overrides (the file's structure) that turn the scenario's system into the
    identification set-up: only the units' FMUs and their accelerometers, the trial's
    controllers/stimuli/connections removed, the units' couplings off, one noise
    stimulus + exciter + aaKF per unit."""
    units = cfg["units"]
    keep = {u["role"] for u in units.values()} | {u["accelerometer"] for u in units.values()}
    fmus = {r: None for r in names["fmus"] if r not in keep}
    for u in units.values():
        if u["fmu_parameters"]:
            fmus[u["role"]] = {"parameters": dict(u["fmu_parameters"])}
    controllers = {c: None for c in names["controllers"]}
    stimuli = {s: None for s in names["stimuli"]}
    connections = []
    record = []
    r = cfg["lead_m"] / (2 * math.pi)
    kp = float(cfg["hold_N_per_m"]) * r * r / float(cfg["Kt_nominal_Nm_per_A"])
    for j, (name, u) in enumerate(units.items()):
        role, acc = u["role"], u["accelerometer"]
        stimuli[f"id_i_{name}"] = {"type": "band_limited_noise",
                                   "params": {**cfg["excitation"], "stream": 100 + j}}
        controllers[f"id_exc_{name}"] = {
            "type": "excitation_hold", "params": {"Kp_A_per_rad": kp},
            "wiring": {"i_exc": f"stim.id_i_{name}", "theta_enc": f"{role}.{u['encoder']}"},
            "outputs": {"i_cmd": f"{role}.{u['current']}"}}
        controllers[f"id_aakf_{name}"] = {
            "type": "aakf", "params": dict(cfg["aakf"]),
            "wiring": {"theta_enc": f"{role}.{u['encoder']}", "acc_meas": f"{acc}.acc_meas"}}
        connections.append({"from": f"{role}.{u['acceleration']}", "to": f"{acc}.a_true",
                            "sequential": True})
        record += [f"{role}.{u['current']}", f"{role}.{u['encoder']}",
                   f"id_aakf_{name}.omega_rad_s"]
    return {"system": {"fmus": fmus, "connections": connections},
            "controllers": controllers, "stimuli": stimuli, "record": record}


def true_values(system, unit: dict) -> dict:
    """The unit's J, b, fc, Kt as its FMU runs them (set values, else start values);
    NaN for one the FMU has no parameter of that name for (a user's FMU bound to the
    role by its contract need not expose them: the report then shows no truth)."""
    names = system.roles[unit["role"]].variables      # through the role's binding
    known = {k: var for k, var in unit["true_parameters"].items() if var in names}
    got = fmu_values(system, unit["role"], known)
    return {k: got.get(k, math.nan) for k in unit["true_parameters"]}


def observer_overrides(cfg: dict, used: dict) -> dict:
    """Controller overrides building each unit's DOB/RFOB from ``used`` (unit -> J, b,
    fc, Kt), times ``observer_scale``."""
    out = {}
    scale = cfg["observer_scale"] or {}
    for name, u in cfg["units"].items():
        v = used[name]
        for c in u["dob"]:
            s = {"J": 1.0, "Kt": 1.0, **scale.get(c, {})}
            out[c] = {"params": {"Jn_kg_m2": v["J"] * s["J"], "Ktn_Nm_per_A": v["Kt"] * s["Kt"]}}
        for c in u["rfob"]:
            s = {"J": 1.0, "b": 1.0, "fc": 1.0, "Kt": 1.0, **scale.get(c, {})}
            out[c] = {"params": {"J_kg_m2": v["J"] * s["J"], "b_Nms_per_rad": v["b"] * s["b"],
                                 "fc_Nm": v["fc"] * s["fc"], "Kt_Nm_per_A": v["Kt"] * s["Kt"]}}
    return out


def observer_readback(system, cfg: dict) -> dict:
    """The parameters of the DOB/RFOB blocks as built (values ``obs_<ctrl>_<p>``)."""
    names = {c for u in cfg["units"].values() for c in list(u["dob"]) + list(u["rfob"])}
    out = {}
    for c in system.controllers:
        if c.name not in names:
            continue
        p = c.block.params
        if hasattr(p, "Jn_kg_m2"):
            out[f"obs_{c.name}_J"] = p.Jn_kg_m2
            out[f"obs_{c.name}_Kt"] = p.Ktn_Nm_per_A
        else:
            out[f"obs_{c.name}_J"] = c.block.J
            out[f"obs_{c.name}_b"] = c.block.b
            out[f"obs_{c.name}_fc"] = c.block.fc
            out[f"obs_{c.name}_Kt"] = c.block.Kt
    missing = names - {k.split("_", 1)[1].rsplit("_", 1)[0] for k in out}
    if missing:
        raise ValueError(f"startup_identification: observer(s) {sorted(missing)} not in the "
                         f"main phase's controllers")
    return out


def identify(run, build, ctx, cfg: dict):
    """Phase 1: co-simulate the excitation and run the RLS. Returns (RunResult,
    identified: unit -> {J, b, fc, Kt}, travel: unit -> m)."""
    from cosim.master import Master
    from cosim.trials.identification import rls_history
    dur = float(cfg["duration_s"])
    n = dur / run.step
    if abs(n - round(n)) > 1e-9:
        raise ValueError(f"startup_identification.duration_s {dur} is not a whole number "
                         f"of steps of {run.step} s")
    saved = ctx.duration_s
    ctx.duration_s = dur                 # the noise stimuli are drawn for this length
    ctx.phase = "identification"
    try:
        system, record = build(identification_overrides(ctx.state["_names"], cfg))
    finally:
        ctx.duration_s = saved
    res = Master(system, list(dict.fromkeys(record))).run(dur)
    s = res.signals
    Kt_n = float(cfg["Kt_nominal_Nm_per_A"])
    ident, travel = {}, {}
    for name, u in cfg["units"].items():
        role = u["role"]
        th = np.asarray(s[f"{role}.{u['encoder']}"])
        hist = rls_history(s[f"{role}.{u['current']}"], s[f"id_aakf_{name}.omega_rad_s"],
                           run.step, Kt_n, th, **dict(cfg["rls"]))
        final = hist[-1]
        if not np.all(np.isfinite(final)) or final[0] <= 0:
            raise ValueError(f"startup identification of {name}: RLS gave J, b, fc = {final}")
        ident[name] = {"J": float(final[0]), "b": float(final[1]), "fc": float(final[2]),
                       "Kt": Kt_n}
        travel[name] = float(np.max(np.abs(th - th[0]))) * cfg["lead_m"] / (2 * math.pi)
    return res, ident, travel


def identification_work_s(run, parameters) -> float:
    """Simulated time of a run [s]: the start-up identification and the main phase
    (the suite's estimate of a run's cost)."""
    raw = (parameters or {}).get("startup_identification") or {}
    return float(raw.get("duration_s", DEFAULTS["duration_s"])) + float(run.duration)


@procedure("startup_identification", work=identification_work_s)
def startup_identification(run, build, ctx):
    """Start-up RLS identification of each unit, then the trial with its DOB/RFOB
    built from the identified J, b, fc (the thesis chain, Sec. 2.3 -> 2.5.3/2.5.4)."""
    return identify_then_run(run, build, ctx)[0]


def identify_then_run(run, build, ctx) -> tuple[ProcedureResult, dict]:
    """The ``startup_identification`` procedure's result and the overrides its main
    phase was built with (the units' DOB/RFOB from the identified values), so that a
    procedure running the main phase again (e.g. at other observer bandwidths) builds
    the same observers: ``build(deep_merge(main_overrides, more))``."""
    from cosim.master import Master
    cfg = config(ctx.parameters)
    # which roles, controllers and stimuli the run's trial has (to remove them for the
    # identification): read from the System the file builds (not run, nothing stepped)
    system, _ = build()
    ctx.state["_names"] = {"fmus": list(system.roles),
                           "controllers": [c.name for c in system.controllers],
                           "stimuli": list(system.stimuli)}
    for slave in system.roles.values():
        slave.terminate()
    # "true": the unit as the main phase runs it (the plant the observers act on); read
    # before the runs: a unit without them would end the run as non-finite values
    truth = {name: true_values(system, u) for name, u in cfg["units"].items()}
    lack = {n: [k for k, x in v.items() if math.isnan(x)] for n, v in truth.items()}
    lack = {n: ks for n, ks in lack.items() if ks}
    if lack:
        n = next(iter(lack))
        raise ValueError(
            f"startup_identification: the identified J, b, fc, Kt are compared with each "
            f"unit's true values, and the FMU of unit {n!r} (role "
            f"{cfg['units'][n]['role']!r}) has no parameter for {lack[n]}: map each to the "
            f"FMU's own parameter in the role's binding (map: {{{lack[n][0]}: <its "
            f"parameter>}}, units: {{{lack[n][0]}: <its unit>}})")
    id_res, ident, travel = identify(run, build, ctx, cfg)
    ctx.phase = "main"
    used = ident if cfg["source"] == "identified" else truth
    if cfg["source"] != "identified":
        bad = {n: [k for k, x in v.items() if math.isnan(x)] for n, v in truth.items()}
        bad = {n: ks for n, ks in bad.items() if ks}
        if bad:
            raise ValueError(f"startup_identification: source {cfg['source']!r} needs the "
                             f"units' true parameters; the FMUs lack {bad} (set "
                             f"true_parameters to their parameter names)")
    main_overrides = {"controllers": observer_overrides(cfg, used)}
    system, record = build(main_overrides)
    obs = observer_readback(system, cfg)
    main = Master(system, record).run(run.duration)
    out = ProcedureResult(runs={"main": main, "identification": id_res})
    table = {}
    for name in cfg["units"]:
        row = {}
        for p in PARAMS:
            row[p] = {"identified": ident[name][p], "true": truth[name][p],
                      "err_pct": 100.0 * (ident[name][p] / truth[name][p] - 1.0)}
            out.values[f"{p}_id_{name}"] = ident[name][p]
            out.values[f"{p}_true_{name}"] = truth[name][p]
            out.values[f"{p}_err_pct_{name}"] = row[p]["err_pct"]
        row["Kt"] = {"nominal": ident[name]["Kt"], "true": truth[name]["Kt"]}
        out.values[f"Kt_n_{name}"] = ident[name]["Kt"]
        out.values[f"Kt_true_{name}"] = truth[name]["Kt"]
        out.values[f"id_travel_mm_{name}"] = 1e3 * travel[name]
        table[name] = row
    out.values.update(obs)
    out.artifacts["startup_identification"] = {
        "source": cfg["source"], "units": table, "observers": obs,
        "observer_units": {n: list(u["dob"]) + list(u["rfob"]) for n, u in cfg["units"].items()},
        "observer_scale": cfg["observer_scale"] or {}, "duration_s": cfg["duration_s"]}
    return out, main_overrides

