"""Patient models of the reaching trials (thesis Table 5) and their progression over the
weekly sessions (Fig. 51).

THIS IS A MODEL, NOT DATA. The thesis gives, per subject, only gender, age, disorder
and affected side (Table 5), two sessions' error tables (Tables 7-8) and the pre/post
MAE trends of Fig. 51 (a plot whose values are not in the text). Everything below --
where the impairment is, how large, how attention lapses look, how fast a patient
recovers -- is a documented assumption built on the HumanArm2D profiles of
:mod:`cosim.devices.human_arm`, chosen so that the simulated errors are of the order of
Tables 7-8 (a few mm for the stroke subject, tens of mm without assistance for the
low-attention subject).

Subjects (Table 5; trials with the affected arm for 1-2, the dominant arm for 3-4)
--------------------------------------------------------------------------------
1. male, 72, stroke, left side affected: ``stroke_localised`` profile, the arm's
   stiffness lost by 85 % in a region of 4 cm radius on the left-diagonal reach
   (centred 10 cm along it from the start point); weaker (scale_K 0.8) and more
   viscous (scale_b 1.3) arm elsewhere.
2. male, 73, stroke, right side affected: ``stroke_localised``, the region is at the
   far end of the straight-ahead reach (3.5 cm radius, 80 %), another place and
   direction than subject 1.
3. female, 83, dementia: ``low_attention``, no motor impairment (passive arm
   properties -- mass, viscosity, grasp -- of the healthy profile); attention drifts
   continuously: the pull towards the target (and its feed-forward) follows a raised
   cosine between full attention and none over a 30 s cycle (``lapse_duration =
   lapse_period = 30 s``, ``att_min = 0``), and the attentive pull is weak
   (``scale_K = 0.21``: 42 N/m). The thesis: "low cognitive skills ... affected their
   ability in maintaining their attention focused on the task"; "in free movement
   trials tracking performances got strongly worse". CALIBRATED to the motors-OFF
   pre assessment of Table 8 only (trial 1: MAE 28.94 / 28.39 mm, total 28.67 mm),
   with the X-Y table friction calibrated on Table 7 (0.5 N, 1 N s/m on both axes):
   scale_K 0.21 gives 30.07 / 27.42 mm (total 28.74). Motors-ON errors are NOT
   calibrated: they are what the controller makes of this patient (the held-out
   check of the effective gain, docs/decisions.md).
4. female, 76, Parkinsonism: ``parkinsonism_tremor`` (5 Hz, 1.5 N tremor force,
   rigidity as 1.5x viscosity) with 5 s lapses every 30 s down to 20 % attention.
   Not calibrated: the thesis gives no table for subject 4 (Fig. 51 is not readable).

Magnitudes against Tables 7-8 (motors OFF, week 1) are in docs/decisions.md
("Assumed values and Tables 7-8"): with the X-Y table friction calibrated on Table 7
(0.5 N, 1 N s/m on both axes) subject 1's motors-OFF errors land on Table 7 with no
patient change; subject 3 is recalibrated on Table 8 trial 1 with that friction.

Progression: driven by the assistance the robot delivered (a MODEL, not data)
-----------------------------------------------------------------------------
The thesis gives no recovery model; Fig. 51 shows post assessments "typically below"
the pre assessments of a session and "an overall improving trend" over the four
weekly sessions, and attributes both to the training ("the proposed solution have
positive effects"). An earlier version built both into the model (a fixed fraction of
recovery per week and per motors-ON training, whatever the robot did), so RE-7/RE-8
could not fail. Here the recovery is driven by what the controller delivered:

* **dose** of a training: the assistive impulse D = integral of |F_motor| dt [N s],
  with F_motor the force the table's motors applied (Kf times the motor currents;
  zero with the drivers off). For the stroke subjects only the impulse delivered
  inside the impaired region counts (practice of the impaired movement with
  guidance; assist-as-needed puts it there); for the low-attention subjects the whole
  training counts (the force cue keeps them on the task).
* **response** s(D) = 1 - exp(-D / D_ref) in [0, 1): saturating; D_ref (``dose_ref_Ns``)
  is the dose at which practice reaches 63 % of its effect.
* **within a session**: after each training the impaired quantity q (stroke: depth
  of the impaired region; dementia/Parkinsonism: lapse duration) is multiplied by
  1 - r_practice s(D). Fatigue (the thesis's remark on subject 1's fourth training)
  is NOT modelled.
* **between sessions**: the next week's pre-assessment q is the previous week's
  multiplied by 1 - r_week s_bar, s_bar = sum of the session's s(D) / 3 (Table 6's
  three assisted trainings; capped at 1); the stroke subjects regain
  gain_K s_bar of their lost global stiffness (scale_K) per session. The within-
  session gain is not carried over beyond that (consolidation, not retention).
* no spontaneous recovery (chronic stroke, Sec. 3.6) and no session-to-session
  variability: with no assistance delivered (drivers off in every training) the
  patient is the same in every training of every week, so post = pre and the weekly
  slope is 0 exactly -- the negative control of RE-7/RE-8.

r_practice, r_week and gain_K are the earlier fixed rates, now the saturated rates;
D_ref is set to the order of the dose the reaching controller delivers (values and
their basis in cosim/devices/assumptions.py). A controller that assists less (a map
frozen at alpha0, the printed k with too soft a map) produces less recovery; that is
the model's assumption, stated, not evidence about patients.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Mapping

from ..devices.human_arm import human_parameters as _profile_parameters


#: Table 6's number of assisted trainings per session (the weekly response's divisor)
ASSISTED_TRAININGS_PER_SESSION = 3


@dataclasses.dataclass(frozen=True)
class Subject:
    """One subject of Table 5 with the patient model and its progression (a model).

    number, gender, age, disorder, affected_side: Table 5.
    profile, grasp: the cosim.devices.human_arm human-arm profile and grasp it is built on.
    overrides: HumanArm2D parameters changed from the profile (week 0, pre).
    impaired: which parameter recovers ("imp_depth" or "lapse_duration").
    r_week: fractional recovery of ``impaired`` per session at a saturating dose [-].
    r_practice: fractional gain per training at a saturating dose, within a session [-].
    gain_K: fraction of the lost global stiffness regained per session at a saturating
        dose (stroke) [-].
    dose_ref_Ns: assistive impulse at which practice reaches 1 - 1/e of its effect [N s].
    dose_in_region: count only the impulse delivered inside the impaired region
        (stroke) rather than the whole training.
    """

    number: int
    gender: str
    age: int
    disorder: str
    affected_side: str
    profile: str
    grasp: str = "hard"
    overrides: Mapping[str, float] = dataclasses.field(default_factory=dict)
    impaired: str = "imp_depth"
    r_week: float = 0.12
    r_practice: float = 0.04
    gain_K: float = 0.0
    dose_ref_Ns: float = 10.0
    dose_in_region: bool = False

    @property
    def key(self) -> str:
        return f"S{self.number}"

    def table5(self) -> dict:
        return {"subject": self.number, "gender": self.gender, "age": self.age,
                "disorder": self.disorder, "affected side": self.affected_side}

    def human_parameters(self, impaired_factor: float = 1.0, stiffness_regained: float = 0.0) -> dict:
        """HumanArm2D parameters with the impaired quantity scaled by ``impaired_factor``
        (1: the week-1 pre assessment) and ``stiffness_regained`` (0..1) of the lost
        global stiffness regained. :class:`Course` supplies both from the doses."""
        if impaired_factor < 0 or not 0.0 <= stiffness_regained <= 1.0:
            raise ValueError(f"{self.key}: impaired_factor >= 0 and 0 <= stiffness_regained <= 1 "
                             f"required, got {impaired_factor}, {stiffness_regained}")
        p = _profile_parameters(self.profile, self.grasp, "HumanArm2D", **self.overrides)
        q = p[self.impaired] * impaired_factor
        if self.impaired == "imp_depth":
            q = min(q, 1.0)
        if self.impaired == "lapse_duration":
            q = min(q, p["lapse_period"])
        p[self.impaired] = q
        if stiffness_regained:
            p["scale_K"] = p["scale_K"] + (1.0 - p["scale_K"]) * stiffness_regained
        return p

    def response(self, dose_Ns: float) -> float:
        """s(D) = 1 - exp(-D / D_ref): the practice response to an assistive dose [-]."""
        if not dose_Ns >= 0:
            raise ValueError(f"{self.key}: dose must be >= 0 N s, got {dose_Ns}")
        return 1.0 - math.exp(-dose_Ns / self.dose_ref_Ns)


class Course:
    """A subject's course of weekly sessions, with the progression driven by the
    assistance delivered (module docstring). Use: ``parameters()`` for the next
    training, ``practice(dose)`` after it, ``end_session()`` after the last training
    of a session."""

    def __init__(self, subject: Subject):
        self.subject = subject
        self.reset()

    def reset(self) -> None:
        self.week_factor = 1.0          # impaired quantity at the session's start / week 1
        self.practice_factor = 1.0      # within the current session
        self.stiffness_regained = 0.0
        self.session_responses: list[float] = []
        self.history: list[dict] = []   # one dict per finished session

    def parameters(self) -> dict:
        """HumanArm2D parameters of the next training."""
        return self.subject.human_parameters(self.week_factor * self.practice_factor,
                                             self.stiffness_regained)

    def practice(self, dose_Ns: float) -> float:
        """Record a training's assistive dose [N s]; returns its response s(D)."""
        s = self.subject.response(dose_Ns)
        self.practice_factor *= 1.0 - self.subject.r_practice * s
        self.session_responses.append(s)
        return s

    def end_session(self) -> dict:
        """Consolidate the session: the next week's pre-assessment patient."""
        sub = self.subject
        s_bar = min(1.0, sum(self.session_responses) / ASSISTED_TRAININGS_PER_SESSION)
        rec = {"responses": list(self.session_responses), "s_bar": s_bar,
               "week_factor": self.week_factor, "post_practice_factor": self.practice_factor}
        self.week_factor *= 1.0 - sub.r_week * s_bar
        self.stiffness_regained = min(1.0, self.stiffness_regained + sub.gain_K * s_bar)
        self.practice_factor = 1.0
        self.session_responses = []
        self.history.append(rec)
        return rec


#: the four subjects of Table 5 (the patient models are assumptions; see module doc)
SUBJECTS: dict[str, Subject] = {s.key: s for s in [
    Subject(1, "male", 72, "stroke", "left", "stroke_localised",
            overrides={"imp_cx": -0.0707, "imp_cy": -0.0293, "imp_radius": 0.04,
                       "imp_depth": 0.85, "imp_visc": 1.0, "scale_K": 0.8, "scale_b": 1.3},
            impaired="imp_depth", r_week=0.12, r_practice=0.04, gain_K=0.1, dose_in_region=True,
            dose_ref_Ns=10.0),
    Subject(2, "male", 73, "stroke", "right", "stroke_localised",
            overrides={"imp_cx": 0.0, "imp_cy": 0.03, "imp_radius": 0.035,
                       "imp_depth": 0.8, "imp_visc": 1.0, "scale_K": 0.7, "scale_b": 1.3},
            impaired="imp_depth", r_week=0.10, r_practice=0.04, gain_K=0.1, dose_in_region=True,
            dose_ref_Ns=10.0),
    Subject(3, "female", 83, "dementia", "-", "low_attention",
            overrides={"lapse_start": 0.0, "lapse_period": 30.0, "lapse_duration": 30.0,
                       "att_min": 0.0, "scale_K": 0.21},
            impaired="lapse_duration", r_week=0.08, r_practice=0.03, dose_ref_Ns=100.0),
    Subject(4, "female", 76, "Parkinsonism", "-", "parkinsonism_tremor",
            overrides={"lapse_start": 8.0, "lapse_period": 30.0, "lapse_duration": 5.0,
                       "att_min": 0.2},
            impaired="lapse_duration", r_week=0.06, r_practice=0.03, dose_ref_Ns=100.0),
]}


def subject(key: str) -> Subject:
    """Look a subject up by key ('S1'..'S4') or number."""
    k = key if str(key).startswith("S") else f"S{key}"
    if k not in SUBJECTS:
        raise KeyError(f"unknown subject {key!r}; known: {sorted(SUBJECTS)}")
    return SUBJECTS[k]
