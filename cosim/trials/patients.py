"""Patient models of the reaching trials (thesis Table 5) and their progression over the
weekly sessions (Fig. 51).

THIS IS A MODEL, NOT DATA. The thesis gives, per subject, only gender, age, disorder
and affected side (Table 5), two sessions' error tables (Tables 7-8) and the pre/post
MAE trends of Fig. 51 (a plot whose values are not in the text). Everything below --
where the impairment is, how large, how attention lapses look, how fast a patient
recovers -- is a documented assumption built on the HumanArm2D profiles of
:mod:`cosim.profiles`, chosen so that the simulated errors are of the order of
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
   (``scale_K = 0.3``: 60 N/m). The thesis: "low cognitive skills ... affected their
   ability in maintaining their attention focused on the task"; "in free movement
   trials tracking performances got strongly worse". CALIBRATED to the motors-OFF
   pre assessment of Table 8 only (trial 1: MAE 28.94 / 28.39 mm, total 28.7 mm);
   measured with this model: 35.1 / 24.3 mm (total 29.7) -- the y error is lower
   because the assumed XYTable friction is lower on y. The earlier model (10 s lapses
   every 20 s down to 5 %) gave 8.1 / 6.9 mm (total 7.5), a quarter of Table 8, so the
   controller had almost nothing to correct. Motors-ON errors are NOT calibrated: they
   are what the controller makes of this patient (measured: 16.1 / 11.7 mm against
   Table 8's 6-7 / 4.5-6 mm).
4. female, 76, Parkinsonism: ``parkinsonism_tremor`` (5 Hz, 1.5 N tremor force,
   rigidity as 1.5x viscosity) with 5 s lapses every 30 s down to 20 % attention.
   Not calibrated: the thesis gives no table for subject 4 (Fig. 51 is not readable).

Magnitudes against Tables 7-8 (motors OFF, trial 1, week 1, measured with the
XYTable/HumanArm2D FMUs): subject 1 model 9.9 / 5.3 mm (x / y) against Table 7's
5.45 / 5.19 mm (x too large: the impaired region lies on the left diagonal and the
assumed x friction is 1 N); subject 3 model 35.1 / 24.3 mm against Table 8's
28.94 / 28.39 mm.

Progression (weeks w = 0..3, trainings i = 0..4 of a session)
-------------------------------------------------------------
* weekly recovery: the impaired quantity q (stroke: depth of the impaired region;
  dementia/Parkinsonism: lapse duration) follows q0 (1 - r_week)^w. Stroke subjects
  also regain global stiffness: scale_K + (1 - scale_K) * gain_K * w. The tremor
  amplitude does not change (Parkinsonism is progressive; training is not expected to
  reduce it).
* within a session, practice with assistance: q is multiplied by
  (1 - r_practice)^n with n the number of motors-ON trainings before training i
  (Table 6: n = 0 for the pre assessment, 3 for the post assessment). Fatigue (the
  thesis's remark on the fourth training of subject 1) is NOT modelled.
* session-to-session variability: q is multiplied by a factor 1 + u, u uniform in
  +-``variability``, drawn from a generator seeded by (subject, week): the same for
  the five trainings of a session, so pre and post differ only by practice.
"""
from __future__ import annotations

import dataclasses
from typing import Mapping

import numpy as np

from ..profiles import human_parameters as _profile_parameters


@dataclasses.dataclass(frozen=True)
class Subject:
    """One subject of Table 5 with the patient model and its progression (a model).

    number, gender, age, disorder, affected_side: Table 5.
    profile, grasp: the cosim.profiles human-arm profile and grasp it is built on.
    overrides: HumanArm2D parameters changed from the profile (week 0, pre).
    impaired: which parameter recovers ("imp_depth" or "lapse_duration").
    r_week: fractional recovery of ``impaired`` per week [-].
    r_practice: fractional gain per assisted (motors ON) training within a session [-].
    gain_K: fraction of the lost global stiffness regained per week (stroke) [-].
    variability: half-width of the uniform session factor on ``impaired`` [-].
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
    variability: float = 0.08

    @property
    def key(self) -> str:
        return f"S{self.number}"

    def table5(self) -> dict:
        return {"subject": self.number, "gender": self.gender, "age": self.age,
                "disorder": self.disorder, "affected side": self.affected_side}

    def session_factor(self, week: int) -> float:
        """Deterministic session-to-session factor 1 + u (seeded by subject and week)."""
        rng = np.random.default_rng([self.number, week, 51])
        return 1.0 + self.variability * (2.0 * rng.random() - 1.0)

    def human_parameters(self, week: int = 0, training: int = 0,
                         motors: tuple = (False, True, True, True, False)) -> dict:
        """HumanArm2D parameters for training ``training`` (0..4) of week ``week`` (0..)."""
        if week < 0 or training < 0:
            raise ValueError("week and training must be >= 0")
        p = _profile_parameters(self.profile, self.grasp, "HumanArm2D", **self.overrides)
        n_assisted = sum(1 for on in motors[:training] if on)
        q = p[self.impaired] * (1.0 - self.r_week) ** week * (1.0 - self.r_practice) ** n_assisted
        q *= self.session_factor(week)
        if self.impaired == "imp_depth":
            q = min(q, 1.0)
        if self.impaired == "lapse_duration":
            q = min(q, p["lapse_period"])
        p[self.impaired] = q
        if self.gain_K:
            p["scale_K"] = p["scale_K"] + (1.0 - p["scale_K"]) * min(1.0, self.gain_K * week)
        return p


#: the four subjects of Table 5 (the patient models are assumptions; see module doc)
SUBJECTS: dict[str, Subject] = {s.key: s for s in [
    Subject(1, "male", 72, "stroke", "left", "stroke_localised",
            overrides={"imp_cx": -0.0707, "imp_cy": -0.0293, "imp_radius": 0.04,
                       "imp_depth": 0.85, "imp_visc": 1.0, "scale_K": 0.8, "scale_b": 1.3},
            impaired="imp_depth", r_week=0.12, r_practice=0.04, gain_K=0.1),
    Subject(2, "male", 73, "stroke", "right", "stroke_localised",
            overrides={"imp_cx": 0.0, "imp_cy": 0.03, "imp_radius": 0.035,
                       "imp_depth": 0.8, "imp_visc": 1.0, "scale_K": 0.7, "scale_b": 1.3},
            impaired="imp_depth", r_week=0.10, r_practice=0.04, gain_K=0.1),
    Subject(3, "female", 83, "dementia", "-", "low_attention",
            overrides={"lapse_start": 0.0, "lapse_period": 30.0, "lapse_duration": 30.0,
                       "att_min": 0.0, "scale_K": 0.3},
            impaired="lapse_duration", r_week=0.08, r_practice=0.03),
    Subject(4, "female", 76, "Parkinsonism", "-", "parkinsonism_tremor",
            overrides={"lapse_start": 8.0, "lapse_period": 30.0, "lapse_duration": 5.0,
                       "att_min": 0.2},
            impaired="lapse_duration", r_week=0.06, r_practice=0.03),
]}


def subject(key: str) -> Subject:
    """Look a subject up by key ('S1'..'S4') or number."""
    k = key if str(key).startswith("S") else f"S{key}"
    if k not in SUBJECTS:
        raise KeyError(f"unknown subject {key!r}; known: {sorted(SUBJECTS)}")
    return SUBJECTS[k]
