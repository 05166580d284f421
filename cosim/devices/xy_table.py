"""The 2-DOF X-Y table (thesis Sec. 3.4, Table 4): two direct-drive linear motors, the
lower axis carrying the upper one. Its friction is not in the thesis
(:mod:`cosim.devices.assumptions`)."""
from __future__ import annotations

#: moving mass of the upper axis [kg]
M_UPPER_KG = 0.5
#: moving mass of the lower axis [kg] (it carries the upper axis)
M_LOWER_KG = 1.0
#: force constant of each linear motor [N/A]
KF_N_PER_A = 33.0
#: linear encoder resolution [m] (10 um)
ENCODER_RESOLUTION_M = 10e-6
#: control period [s]
TS_S = 1e-3
#: side of the square workspace [m] (about 40 cm x 40 cm)
WORKSPACE_M = 0.40
#: the workspace is split into GRID x GRID equal squares: P = 36 RBF centres
GRID = 6
