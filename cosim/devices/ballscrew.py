"""The ball-screw unit of the 1-DOF device (thesis Sec. 2.4, Table 1).

A Maxon DC motor turns a ball screw; the handle and the accelerometer sit on the nut.
Two identical units make the bilateral master/slave pair. The Modelica models
(``modelica/RehabSim/BallScrewUnit.mo`` and the rigs built on it) take the same
values from the package of constants ``modelica/RehabSim/Table1.mo``;
``tests/test_cli_layout.py`` checks that the two agree.

Table 1 prints the inertia in kg/m^2 and the viscous friction in N s; the units below
are the physically consistent ones (thesis digest, "Table 1 units").
"""
from __future__ import annotations

import math

#: total inertia at the motor shaft, J = Jm + Jbs = 1.37e-5 + 0.33e-5 [kg m^2]
J_KG_M2 = 1.7e-5
#: viscous friction at the motor shaft [N m s/rad]
B_NM_S_PER_RAD = 1.6e-5
#: Coulomb friction at the motor shaft [N m]
FC_NM = 3e-3
#: motor torque constant [N m/A] (60.3 mN m/A)
KT_NM_PER_A = 0.0603
#: ball-screw lead [m/rev]: x_nut = LEAD_M / (2 pi) * theta_motor
LEAD_M = 0.01
#: incremental encoder on the motor shaft [pulses/rev]
ENCODER_COUNTS_PER_REV = 21600
#: encoder resolution Delta = 2 pi / counts [rad] (eq. 12-13)
ENCODER_RESOLUTION_RAD = 2 * math.pi / ENCODER_COUNTS_PER_REV
#: control period of the real-time loop [s]
TS_S = 1e-3
