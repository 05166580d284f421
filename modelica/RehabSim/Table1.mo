within RehabSim;
package Table1 "Constants of the ball-screw unit given by the thesis's Table 1, written once: the models take their defaults from here"
  constant Real J(unit = "kg.m2") = 1.7e-5 "total inertia at the motor shaft, J = Jm + Jbs = 1.37e-5 + 0.33e-5";
  constant Real Kt(unit = "N.m/A") = 0.0603 "motor torque constant, 60.3 mNm/A";
  constant Real delta_enc(unit = "rad") = 2.908882086657216e-4 "encoder resolution, 2 pi/21600 rad: 21600 pulses/rev (pymoca folds no expression in a package constant, so the quotient is written out)";
end Table1;
