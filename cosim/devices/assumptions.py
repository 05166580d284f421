"""Every value the models and trials use that the thesis does not give, in one place.

Each :class:`Assumption` has a value with its unit, WHERE it is used (the Modelica
parameter default, the Python constant or the scenario line that holds it) and its
SOURCE: what chose it.

``basis`` says what kind of source it is:

``assumed``
    an order of magnitude or an engineering choice, with the reason; nothing in the
    thesis or a datasheet pins it (e.g. the X-Y table's friction: the thesis only says
    "low friction losses and good back-drivability").
``derived``
    computed from other values by a stated rule (e.g. LuGre bristle damping = critical
    damping of the presliding mode); it follows its inputs.
``calibrated``
    chosen so that a simulated figure matches a number the thesis gives (the figure,
    the thesis's number and the simulated value are in ``source``).
``datasheet``
    a component's datasheet, not the thesis.

``used_in`` locations (each is cross-checked against the source it names by
``tests/test_devices_assumptions.py``, so this table cannot drift silently):

* ``modelica/RehabSim/<Model>.mo:<parameter>``: the parameter's default;
* ``<python.module>:<NAME>[key].attr...``: a Python constant (dict keys in ``[]``,
  attributes and dataclass field defaults after ``.``);
* ``scenarios/<file>.yaml:<dotted.path>``: a value set in a scenario file.

This module is data only and imports nothing from the package beyond the devices'
Table values (lowest floor).
"""
from __future__ import annotations

import dataclasses

from .ballscrew import ENCODER_COUNTS_PER_REV, J_KG_M2

BASES = ("assumed", "derived", "calibrated", "datasheet")


@dataclasses.dataclass(frozen=True)
class Assumption:
    """One value the thesis does not give: name, value [unit], where used, source."""

    group: str
    name: str
    value: float
    unit: str
    used_in: tuple[str, ...]
    basis: str
    source: str

    def __post_init__(self):
        if self.basis not in BASES:
            raise ValueError(f"{self.name}: basis must be one of {BASES}, got {self.basis!r}")
        if not self.used_in:
            raise ValueError(f"{self.name}: used_in must name at least one place")


_A = Assumption
_XY = "modelica/RehabSim/XYTable.mo"
_BS = "modelica/RehabSim/BallScrewUnit.mo"
_ACC = "modelica/RehabSim/Accelerometer.mo"
_H2 = "modelica/RehabSim/HumanArm2D.mo"
_H1 = "modelica/RehabSim/HumanArm1D.mo"
_PAT = "cosim.trials.patients:SUBJECTS"
_LIT = ("assumed: order of magnitude of the hand impedance in the literature the thesis "
        "cites for eq. 75 ([114]-[117]: stiffness 1e2-1e3 N/m, viscosity 5-30 N s/m, "
        "effective mass 0.5-2 kg); Fig. 42/44 plot the identified admittances but the "
        "values are not readable from the thesis text")

ASSUMPTIONS: tuple[Assumption, ...] = (
    # ------------------------------------------------------------------ X-Y table
    _A("X-Y table friction", "Coulomb friction, x axis", 0.5, "N",
       (f"{_XY}:fc_x", f"{_XY}:fs_x"), "calibrated",
       "calibrated on Table 7 motors OFF (S1, trials 1 and 5: MAE x 5.01, y 4.57 mm): the "
       "thesis gives no friction (Sec. 3.4: 'low friction losses and good "
       "back-drivability'); the former assumed 1 N made S1's OFF x error 9.4 mm (1.9x "
       "Table 7) with y on Table 7. With x = y (0.5 N, 1 N s/m) S1 week 1 OFF: x 4.75 vs "
       "5.01, y 4.98 vs 4.57 mm, no patient change (docs/decisions.md)"),
    _A("X-Y table friction", "Coulomb friction, y axis", 0.5, "N",
       (f"{_XY}:fc_y", f"{_XY}:fs_y"), "assumed",
       "assumed (no thesis source); Table 7's motors-OFF y error (4.57 mm) is met with it "
       "(model 4.98 mm, S1 week 1), and the x axis is calibrated to the same value"),
    _A("X-Y table friction", "viscous friction, x axis", 1.0, "N.s/m", (f"{_XY}:b_x",),
       "calibrated", "calibrated with fc_x on Table 7 motors OFF (= b_y): 0.02 N at the "
       "1.8 cm/s target speed; the former assumed 2 N s/m had no source"),
    _A("X-Y table friction", "viscous friction, y axis", 1.0, "N.s/m", (f"{_XY}:b_y",),
       "assumed", "assumed (no thesis source): 0.02 N at 1.8 cm/s"),
    _A("X-Y table friction", "LuGre bristle stiffness, x", 1e6, "N/m", (f"{_XY}:sigma0_x",),
       "derived", "presliding fs_x/sigma0_x = 0.5 um = 0.05 count of the 10 um encoder "
       "(Table 4): the table holds under a sub-breakaway force without visible creep"),
    _A("X-Y table friction", "LuGre bristle stiffness, y", 5e5, "N/m", (f"{_XY}:sigma0_y",),
       "derived", "presliding fs_y/sigma0_y = 1 um = 0.1 encoder count (Table 4)"),
    _A("X-Y table friction", "LuGre bristle damping, x", 2450.0, "N.s/m", (f"{_XY}:sigma1_x",),
       "derived", "2 sqrt(sigma0_x (m_low + m_up)): critical damping of the presliding mode "
       "with Table 4's 1.5 kg"),
    _A("X-Y table friction", "LuGre bristle damping, y", 1000.0, "N.s/m", (f"{_XY}:sigma1_y",),
       "derived", "2 sqrt(sigma0_y m_up) with Table 4's 0.5 kg"),
    _A("X-Y table friction", "bristle damping fade speed", 1e-3, "m/s", (f"{_XY}:vd",),
       "derived", "below the passivity limits 3.8 mm/s (x), 4.7 mm/s (y) "
       "(modelica/RehabSim/README.md, LuGre)"),
    _A("X-Y table end stops", "end-stop stiffness", 1e5, "N/m", (f"{_XY}:k_stop",), "assumed",
       "assumed: a 10 N push penetrates 0.1 mm; 41 Hz on x (README)"),
    _A("X-Y table end stops", "end-stop damping", 200.0, "N.s/m", (f"{_XY}:d_stop",), "assumed",
       "assumed: damping ratio 0.26 on x; acts only while penetrating"),
    # ------------------------------------------------------------------ ball screw
    _A("ball-screw friction model", "LuGre bristle stiffness", 200.0, "N.m/rad",
       (f"{_BS}:sigma0",), "derived",
       f"bristle deflection at breakaway fs/sigma0 = 1.5e-5 rad = 0.05 count of the "
       f"{ENCODER_COUNTS_PER_REV} pulse/rev encoder (Table 1); the thesis gives no presliding "
       f"data"),
    _A("ball-screw friction model", "LuGre bristle damping", 0.117, "N.m.s/rad",
       (f"{_BS}:sigma1",), "derived",
       f"2 sqrt(sigma0 J) with Table 1's J = {J_KG_M2:g} kg m^2: critical damping of the "
       "presliding mode (546 Hz)"),
    _A("ball-screw friction model", "bristle damping fade speed", 0.1, "rad/s",
       (f"{_BS}:wd",), "derived", "passivity of the LuGre model needs wd <= 0.24 rad/s "
       "(README)"),
    # ------------------------------------------------------------------ accelerometer
    _A("accelerometer (ADXL335)", "initial bias b0", 0.1, "m/s2",
       (f"{_ACC}:b0", "scenarios/free_motion.yaml:system.fmus.acc.parameters.b0"), "assumed",
       "assumed: residual 0 g offset after calibration, about 10 mg; Table 2 gives only its "
       "temperature drift (1 mg/degC). It is the truth FM-2/FM-3 ask the aaKF to find "
       "(Fig. 25 shows an estimate of this order, not readable)"),
    _A("accelerometer (ADXL335)", "bias random walk (1 s)", 1e-3, "m/s2",
       (f"{_ACC}:sigma_rw",), "assumed",
       "assumed: standard deviation of the bias change over 1 s (eq. 15 gives the form, "
       "not the size)"),
    _A("accelerometer (ADXL335)", "ADC quantum", 20.0 / 65536, "V",
       (f"{_ACC}:adc_lsb",), "datasheet",
       "Sensoray 626: 16 bit over +-10 V (the thesis names the board, not the resolution)"),
    _A("accelerometer (ADXL335)", "noise generator hold period", 1e-4, "s",
       (f"{_ACC}:T_noise",), "assumed",
       "modelling choice: Nyquist 5 kHz above the 1600 Hz band of Table 2"),
    # ------------------------------------------------------------------ load cell
    _A("load cell", "stiffness of the load cell and mounting", 2e5, "N/m",
       ("modelica/RehabSim/LoadCell.mo:k_lc", "modelica/RehabSim/ZeroForceRig.mo:k_cell"),
       "assumed", "assumed: the thesis gives no load-cell stiffness (Sec. 2.5.3, Fig. 27)"),
    _A("load cell", "stiffness in the zero-force scenario", 2e4, "N/m",
       ("scenarios/zero_force.yaml:system.fmus.rig.parameters.k_cell",
        "scenarios/faults.yaml:system.fmus.rig.parameters.k_cell"), "derived",
       "lowered from 2e5 so that the DOB/RFOB loop is stable: Routh needs "
       "g > k_cell/d_cell = 133 rad/s < g = 500 rad/s (scenarios/zero_force.yaml)"),
    _A("load cell", "damping of the load cell and mounting", 150.0, "N.s/m",
       ("modelica/RehabSim/LoadCell.mo:d_lc", "modelica/RehabSim/ZeroForceRig.mo:d_cell",
        "scenarios/zero_force.yaml:system.fmus.rig.parameters.d_cell",
        "scenarios/faults.yaml:system.fmus.rig.parameters.d_cell"), "assumed",
       "assumed: no thesis source"),
    _A("load cell", "reading noise (std)", 0.02, "N",
       ("modelica/RehabSim/LoadCell.mo:sigma_lc", "modelica/RehabSim/ZeroForceRig.mo:sigma_cell"),
       "assumed", "assumed: no thesis source"),
    # ------------------------------------------------------------------ wall
    _A("rigid wall (bilateral)", "wall stiffness", 2e5, "N/m",
       ("modelica/RehabSim/RigidWall.mo:k_wall", "modelica/RehabSim/WallUnitRig.mo:k_w",
        "scenarios/bilateral.yaml:system.fmus.slave.parameters.k_w"), "assumed",
       "assumed: the thesis's wall (Sec. 2.5.4, Fig. 32) is 'rigid', no stiffness given"),
    _A("rigid wall (bilateral)", "wall damping", 500.0, "N.s/m",
       ("modelica/RehabSim/RigidWall.mo:d_wall", "modelica/RehabSim/WallUnitRig.mo:d_w",
        "scenarios/bilateral.yaml:system.fmus.slave.parameters.d_w"), "assumed",
       "assumed: acts only while penetrating; no thesis source"),
    _A("rigid wall (bilateral)", "wall position", 0.02, "m",
       ("modelica/RehabSim/RigidWall.mo:x_wall", "modelica/RehabSim/WallUnitRig.mo:x_w",
        "scenarios/bilateral.yaml:system.fmus.slave.parameters.x_w"), "assumed",
       "assumed: 2 cm from home, inside the handle's few-cm travel"),
    # ------------------------------------------------------------------ human arm
    _A("human arm (eq. 75)", "effective hand/arm mass M_h", 1.0, "kg",
       (f"{_H2}:M_h", f"{_H1}:M_h", "cosim.devices.human_arm:_BASE[M_h]"), "assumed", _LIT),
    _A("human arm (eq. 75)", "arm stiffness K_h (healthy)", 200.0, "N/m",
       (f"{_H2}:K_hx", f"{_H2}:K_hy", f"{_H1}:K_h", "cosim.devices.human_arm:_BASE[K_hx]",
        "cosim.devices.human_arm:_BASE[K_hy]"), "assumed",
       _LIT + "; with M_h the tracking mode is 2.3 Hz"),
    _A("human arm (eq. 75)", "arm viscosity b_h (healthy)", 20.0, "N.s/m",
       (f"{_H2}:b_hx", f"{_H2}:b_hy", f"{_H1}:b_h", "cosim.devices.human_arm:_BASE[b_hx]",
        "cosim.devices.human_arm:_BASE[b_hy]"), "assumed", _LIT + "; damping ratio 0.7 with M_h, K_h"),
    _A("human arm (eq. 75)", "stiffness change across the workspace (y)", 0.5, "1/m",
       ("cosim.devices.human_arm:_BASE[K_slope_y]",), "assumed",
       "assumed: +-10 % across 0.4 m; Fig. 43-44 show that it changes, not by how much"),
    _A("grasp (Fig. 41-42)", "hard grasp stiffness", 2500.0, "N/m",
       (f"{_H2}:k_grasp", f"{_H1}:k_grasp", "cosim.devices.human_arm:GRASPS[hard][k_grasp]"), "assumed",
       "assumed: grasp mode 8 Hz with M_h, inside the 20 Hz identification band of Sec. "
       "3.3.1.1; Fig. 42 shows the hard grasp stiffer, values not readable"),
    _A("grasp (Fig. 41-42)", "hard grasp damping", 25.0, "N.s/m",
       (f"{_H2}:b_grasp", f"{_H1}:b_grasp", "cosim.devices.human_arm:GRASPS[hard][b_grasp]"), "assumed",
       "assumed: no thesis value"),
    _A("grasp (Fig. 41-42)", "soft grasp stiffness", 400.0, "N/m",
       ("cosim.devices.human_arm:GRASPS[soft][k_grasp]",), "assumed",
       "assumed: grasp mode 3.2 Hz; no thesis value"),
    _A("grasp (Fig. 41-42)", "soft grasp damping", 4.0, "N.s/m",
       ("cosim.devices.human_arm:GRASPS[soft][b_grasp]",), "assumed", "assumed: no thesis value"),
    _A("arm identification (Sec. 3.3.1.1)", "shaker motion rms per axis", 0.002, "m",
       ("scenarios/human_arm_identification.yaml:stimuli.x.params.rms_m",
        "scenarios/human_arm_identification.yaml:stimuli.y.params.rms_m"), "assumed",
       "assumed: the thesis gives the band (20 Hz), not the amplitude; 2 mm keeps the "
       "hand within the small-signal range of the arm model and the force far above the "
       "reading noise (coherence 0.997 over 0.5-20 Hz)"),
    _A("arm identification (Sec. 3.3.1.1)", "force reading noise (std)", 0.05, "N",
       ("scenarios/human_arm_identification.yaml:parameters.identification.force_noise_N",),
       "assumed", "assumed: the shaker's force sensor is not specified; 2.5x the load "
       "cell's assumed 0.02 N (LoadCell.mo)"),
    _A("arm identification (Sec. 3.3.1.1)", "shaker encoder resolution", 1e-6, "m",
       ("scenarios/human_arm_identification.yaml:parameters.identification.position_quantum_m",),
       "assumed", "assumed: not in the thesis; a common linear-encoder resolution"),
    _A("human arm (eq. 75)", "operator factor on K_h and b_h (bilateral)", 3.0, "1",
       ("scenarios/bilateral.yaml:system.fmus.human.parameters.scale_K",
        "scenarios/bilateral.yaml:system.fmus.human.parameters.scale_b"), "assumed",
       "assumed: an operator pushing firmly, 600 N/m and 60 N s/m (damping ratio about 0.4 "
       "with the rendered unit mass); Fig. 32 gives no arm values"),
    # ------------------------------------------------------------------ patients
    _A("patient S1 (stroke, Table 5)", "pull stiffness factor scale_K", 0.8, "1",
       (f"{_PAT}[S1].overrides[scale_K]",), "assumed",
       "assumed: pull 0.8 x 200 = 160 N/m outside the impaired region. Not fitted: with "
       "the table friction calibrated on Table 7, motors OFF week 1 gives x 4.75 / y "
       "4.98 mm against Table 7's 5.01 / 4.57 mm (mean of trials 1 and 5)"),
    _A("patient S1 (stroke, Table 5)", "viscosity factor scale_b", 1.3, "1",
       (f"{_PAT}[S1].overrides[scale_b]", f"{_PAT}[S2].overrides[scale_b]"), "assumed",
       "assumed: a more viscous impaired arm (S1 and S2)"),
    _A("patient S1 (stroke, Table 5)", "stiffness lost in the impaired region", 0.85, "1",
       (f"{_PAT}[S1].overrides[imp_depth]",), "assumed",
       "assumed: Sec. 3.3.1 says impairments are localised, not how deep"),
    _A("patient S1 (stroke, Table 5)", "impaired region radius", 0.04, "m",
       (f"{_PAT}[S1].overrides[imp_radius]",), "assumed",
       "assumed: placed 10 cm along the left-diagonal reach (left side affected)"),
    _A("patient S2 (stroke, Table 5)", "pull stiffness factor scale_K", 0.7, "1",
       (f"{_PAT}[S2].overrides[scale_K]",), "assumed",
       "assumed: pull 140 N/m; the thesis gives no table for S2"),
    _A("patient S2 (stroke, Table 5)", "stiffness lost in the impaired region", 0.8, "1",
       (f"{_PAT}[S2].overrides[imp_depth]",), "assumed", "assumed: no thesis value"),
    _A("patient S2 (stroke, Table 5)", "impaired region radius", 0.035, "m",
       (f"{_PAT}[S2].overrides[imp_radius]",), "assumed",
       "assumed: at the far end of the straight-ahead reach (right side affected)"),
    _A("patient S3 (dementia, Table 5)", "pull stiffness factor scale_K", 0.21, "1",
       (f"{_PAT}[S3].overrides[scale_K]",), "calibrated",
       "calibrated on Table 8 motors OFF, trial 1 (total MAE (28.94 + 28.39)/2 = 28.67 "
       "mm) with the table friction calibrated on Table 7: 0.20 / 0.21 / 0.22 / 0.25 / "
       "0.30 give 29.34 / 28.74 / 28.20 / 26.66 / 24.51 mm; 0.21: x 30.07, y 27.42 mm "
       "(pull 42 N/m). The motors-ON trainings are not calibrated: they are the held-out "
       "check of the effective gain"),
    _A("patient S3 (dementia, Table 5)", "attention cycle (lapse period = duration)", 30.0, "s",
       (f"{_PAT}[S3].overrides[lapse_period]", f"{_PAT}[S3].overrides[lapse_duration]"),
       "calibrated", "calibrated with scale_K on the same Table 8 trial-1 total (28.67 mm, "
       "with a 1 N x friction and scale_K 0.3): attention follows a "
       "raised cosine between 1 and att_min over 30 s; the earlier 10 s lapses every 20 s "
       "gave 7.5 mm, a quarter of Table 8"),
    _A("patient S3 (dementia, Table 5)", "attention at the middle of a lapse", 0.0, "1",
       (f"{_PAT}[S3].overrides[att_min]",), "calibrated",
       "calibrated with the two above (Table 8 trial 1)"),
    _A("patient S4 (Parkinsonism, Table 5)", "lapses (duration / period)", 5.0, "s",
       (f"{_PAT}[S4].overrides[lapse_duration]",), "assumed",
       "assumed: 5 s every 30 s down to 20 %; no thesis table for S4"),
    _A("patient S4 (Parkinsonism, Table 5)", "tremor force amplitude", 1.5, "N",
       ("cosim.devices.human_arm:HUMAN_PROFILES[parkinsonism_tremor][A_tremor]",), "assumed",
       "assumed: 5 Hz rest tremor (4-6 Hz); no thesis value"),
    _A("patient progression (Fig. 51)", "S1 weekly recovery of the impairment at a saturating dose",
       0.12, "1/session", (f"{_PAT}[S1].r_week",), "assumed",
       "assumed: Fig. 51 is a plot whose values are not in the text, and the thesis gives "
       "no recovery model. The next week's impairment is multiplied by 1 - r_week s_bar, "
       "s_bar the session's practice response to the assistance DELIVERED "
       "(cosim/trials/patients.py): with no assistance there is no recovery (RE-7/RE-8's "
       "negative control)"),
    _A("patient progression (Fig. 51)", "gain per training at a saturating dose (S1, S2)", 0.04, "1",
       (f"{_PAT}[S1].r_practice", f"{_PAT}[S2].r_practice"), "assumed",
       "assumed: within a session the impairment is multiplied by 1 - r_practice s(D) after "
       "each training, s(D) = 1 - exp(-D/D_ref) of its assistive impulse D (zero with the "
       "drivers off)"),
    _A("patient progression (Fig. 51)", "practice dose scale D_ref, stroke (impulse in the impaired region)",
       10.0, "N.s", (f"{_PAT}[S1].dose_ref_Ns", f"{_PAT}[S2].dose_ref_Ns"), "assumed",
       "assumed: the order of the impulse the calibrated controller (k = 1500) delivers "
       "inside S1's impaired region in one assisted training of week 1 (about 9 N s; 5.5 N s "
       "with the printed k = 500), so that the thesis's controller gets about 60 % of the "
       "saturated rates; no thesis value"),
    _A("patient progression (Fig. 51)", "practice dose scale D_ref, low attention (whole-training impulse)",
       100.0, "N.s", (f"{_PAT}[S3].dose_ref_Ns", f"{_PAT}[S4].dose_ref_Ns"), "assumed",
       "assumed: the order of the impulse the calibrated controller delivers to S3 in one "
       "assisted training of week 1 (about 90 N s; 72 N s with k = 500); no thesis value"),
    # ------------------------------------------------------------------ reaching trial
    _A("compliance controller (eq. 71)", "effective update gain k (reaching)", 1500.0, "N/(m2.s)",
       ("scenarios/reaching.yaml:cases.S3_k1500.controllers.ac.params.k_N_per_m2s",),
       "calibrated",
       "calibrated on Table 7 (S1, week 1): total MAE ON/OFF 0.75 (3.59 / 4.79 mm); k = "
       "500 / 1000 / 1500 / 2000 / 3000 give 0.85 / 0.79 / 0.75 / 0.71 / 0.66 (see "
       "docs/decisions.md for the final figures). Held out: Table 8 (S3) ON 6.03 mm, "
       "ON/OFF 0.22. The thesis prints k = 500 (Sec. 3.6; the default of "
       "cosim.trials.reaching:XYComplianceParams and of scenarios/reaching.yaml, on which the "
       "thesis claims are judged); the package's k = 1500 is the extension case S3_k1500 "
       "(RE-4b/RE-4d): nothing in eq. 63-71 gives the factor 3, "
       "it is an effective gain of this plant and these patient models"),
    _A("reaching task (Fig. 48)", "reach length", 0.15, "m",
       ("cosim.trials.reaching:ReachingPath.length_m",
        "cosim.trials.reaching:ReachingTargetParams.length_m"), "assumed",
       "assumed: Fig. 48 is not readable; 18 segments x 15 cm / 1.8 cm/s = 150 s, the "
       "thesis's 'about 150 s'"),
    _A("reaching task (Fig. 48)", "start point y (x = 0)", -0.10, "m",
       ("cosim.trials.reaching:ReachingTargetParams.start_y_m",), "assumed",
       "assumed: 10 cm in front of the workspace centre towards the person"),
    _A("compliance controller (eq. 58)", "damping factor xi", 0.7, "1",
       ("cosim.trials.reaching:XYComplianceParams.xi",), "assumed",
       "assumed: Kd = 2 xi sqrt(Kp m) (physical form of the digest), not given in Sec. 3.5-3.6"),
    _A("compliance controller (eq. 78)", "lower clamp of the map heights a_min", 1.0, "N/m",
       ("cosim.trials.reaching:XYComplianceParams.a_min_N_per_m",), "assumed",
       "assumed: eq. 78 needs a_min > 0, the thesis gives no value (<= alpha0 = 10 N/m)"),
    _A("compliance controller (Sec. 3.4)", "Gaussian width / cell size", 0.5, "1",
       ("cosim.trials.reaching:XYComplianceParams.sigma_over_cell",), "assumed",
       "assumed: the thesis gives the 6 x 6 centres, not the width"),
)



def used_by_models(models) -> list[Assumption]:
    """The assumptions whose value sits in one of these Modelica models (e.g. the FMU
    names of a scenario: XYTable, HumanArm2D) or Python modules (e.g. cosim.trials.reaching)."""
    keys = set(models)
    out = []
    for a in ASSUMPTIONS:
        for loc in a.used_in:
            if loc.startswith("modelica/"):
                m = loc.split(":", 1)[0].rsplit("/", 1)[-1].removesuffix(".mo")
            else:
                m = loc.split(":", 1)[0]
            if m in keys:
                out.append(a)
                break
    return out
