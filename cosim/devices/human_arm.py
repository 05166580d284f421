"""Parameter sets of the human-arm models (RehabSim.HumanArm1D / HumanArm2D).

The human is the second-order impedance of thesis eq. 75 (f_h = M_h x'' + b_h x' +
K_h x per axis), acting as an attraction of the hand towards the target (eq. 79,
f_h1 + f_h2), with a grasp spring-damper between hand and handle. Sec. 3.3.1 says
the parameters vary between people, with the grasp (soft two-finger vs hard
whole-hand grasp, Fig. 41-42) and with the limb configuration, i.e. the position in
the workspace (Fig. 43-44), and that impairments are often localised in parts of
the workspace. The subjects of the reaching trials (Table 5) are two chronic
stroke patients (impaired arm) and two subjects with dementia and Parkinsonism
(no motor impairment, low attention).

Numbers: the identified values of Fig. 42 and Fig. 44 are only plotted (Bode
magnitudes of the admittance), not tabulated, and the figures are not readable
from the thesis text, so the magnitudes below are not the thesis's numbers. They
are orders of magnitude of the hand impedance reported in the literature the thesis
cites for eq. 75 ([114]-[117]: stiffness 10^2-10^3 N/m, viscosity 5-30 N s/m,
effective mass 0.5-2 kg at the hand), chosen so that the tracking bandwidth is
1-2 Hz and the grasp modes fall inside the 20 Hz identification band of Sec.
3.3.1.1. Every value is a modelling assumption, listed in
modelica/RehabSim/README.md; the structure (which parameter changes with what) is
the thesis's.

Keys are the parameter names of RehabSim.HumanArm2D; ``human_parameters`` maps a
profile and a grasp to the parameter dict of either model.
"""
from __future__ import annotations

import math

# Grasp between hand and handle (Fig. 41: (a) soft two-finger grasp, (b) hard
# whole-hand grasp; Fig. 42: the hard grasp transmits more stiffness and damping to
# the handle). With M_h = 1 kg the grasp mode is at about 3 Hz (soft) and 8 Hz (hard).
GRASPS = {
    "soft": {"k_grasp": 400.0, "b_grasp": 4.0},     # N/m, N s/m (assumed magnitudes)
    "hard": {"k_grasp": 2500.0, "b_grasp": 25.0},   # N/m, N s/m (assumed magnitudes)
}

_BASE = {
    # eq. 75 impedance of a healthy adult pulling the hand to the target
    "M_h": 1.0,          # kg, effective hand/arm mass at the handle
    "K_hx": 200.0,       # N/m, attraction stiffness along x
    "K_hy": 200.0,       # N/m, along y
    "b_hx": 20.0,        # N s/m, viscosity along x (damping ratio about 0.7 with M_h)
    "b_hy": 20.0,        # N s/m
    "scale_M": 1.0, "scale_K": 1.0, "scale_b": 1.0,      # person factors
    # limb configuration (Fig. 43-44: the impedance changes between the four test
    # positions): +-10 % stiffness across the 0.4 m workspace along y (assumed)
    "K_slope_x": 0.0,    # 1/m
    "K_slope_y": 0.5,    # 1/m
    # no localised impairment
    "imp_cx": 0.1, "imp_cy": 0.1, "imp_radius": 0.06, "imp_depth": 0.0, "imp_visc": 0.0,
    # no attention lapses
    "lapse_start": 10.0, "lapse_period": 30.0, "lapse_duration": 0.0, "att_min": 0.0,
    # no tremor
    "A_tremor": 0.0, "f_tremor": 5.0, "tremor_phase": 0.0, "tremor_angle": math.pi / 4,
}

HUMAN_PROFILES = {
    # healthy subject (Sec. 3.3.1.1 identification and Sec. 3.5 preliminary test)
    "healthy": dict(_BASE),
    # chronic stroke, impaired arm (Table 5): weaker, more viscous arm overall, and
    # an impairment localised in one part of the workspace (Sec. 3.3.1: "motor
    # impairments are, sometimes, localized in specific area of the workspace"):
    # 80 % of the stiffness lost and viscosity doubled at the centre of a Gaussian
    # region of 6 cm radius, about one of the 6 x 6 RBF cells of Sec. 3.4.
    "stroke_localised": dict(_BASE, scale_K=0.5, scale_b=1.3,
                             imp_cx=0.1, imp_cy=0.1, imp_radius=0.06,
                             imp_depth=0.8, imp_visc=1.0),
    # dementia-like low attention (Table 5: no motor impairment, low attention): the
    # pull towards the target fades to 10 % during 6 s lapses every 25 s; the arm
    # keeps its passive viscosity.
    "low_attention": dict(_BASE, lapse_start=10.0, lapse_period=25.0,
                          lapse_duration=6.0, att_min=0.1),
    # Parkinsonism (Table 5: no motor impairment, low attention): 5 Hz tremor force
    # (rest tremor 4-6 Hz), rigidity as higher viscosity, occasional shorter lapses.
    "parkinsonism_tremor": dict(_BASE, scale_b=1.5, A_tremor=1.5, f_tremor=5.0,
                                lapse_start=15.0, lapse_period=40.0,
                                lapse_duration=4.0, att_min=0.3),
}

# HumanArm1D has one axis (the ball-screw handle): it takes the x-axis values. The
# handle travels a few cm about its home position, so the 1-D impaired region is
# placed 2 cm from home with a 2 cm radius (assumed); override imp_cx/imp_radius to
# move it.
_TO_1D = {"K_hx": "K_h", "b_hx": "b_h", "K_slope_x": "K_slope"}
_ONLY_2D = {"K_hy", "b_hy", "K_slope_y", "imp_cy", "tremor_angle"}
_1D_REGION = {"imp_cx": 0.02, "imp_radius": 0.02}


def human_parameters(profile: str = "healthy", grasp: str = "hard",
                     model: str = "HumanArm2D", **overrides) -> dict:
    """Parameter dict for RehabSim.HumanArm2D or RehabSim.HumanArm1D."""
    if profile not in HUMAN_PROFILES:
        raise KeyError(f"unknown human profile {profile!r}; known: {sorted(HUMAN_PROFILES)}")
    if grasp not in GRASPS:
        raise KeyError(f"unknown grasp {grasp!r}; known: {sorted(GRASPS)}")
    p = dict(HUMAN_PROFILES[profile])
    p.update(GRASPS[grasp])
    if model.endswith("HumanArm1D"):
        p = {_TO_1D.get(k, k): v for k, v in p.items() if k not in _ONLY_2D}
        p.update(_1D_REGION)
    elif not model.endswith("HumanArm2D"):
        raise ValueError(f"not a human-arm model: {model}")
    p.update(overrides)
    return p
