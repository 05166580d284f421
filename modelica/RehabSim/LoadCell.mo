within RehabSim;
model LoadCell "Load cell between two units: stiff spring-damper, force reading with gaussian noise sampled at T_sample (thesis Sec. 2.5.3, Fig. 27)"
  parameter Real k_lc(unit = "N/m", min = 0) = 2e5 "stiffness of the load cell and its mounting (not in the thesis: assumed)";
  parameter Real d_lc(unit = "N.s/m", min = 0) = 150 "damping of the load cell and its mounting (not in the thesis: assumed)";
  parameter Real l0(unit = "m") = 0 "value of x_b - x_a at which the load cell is unloaded";
  parameter Real sigma_lc(unit = "N", min = 0) = 0.02 "standard deviation of the reading noise (assumed)";
  parameter Real T_sample(unit = "s", min = 0) = 1e-3 "sampling period of the reading";
  parameter Integer seed = 2 "seed of the noise generator";
  input Real x_a(unit = "m") "position of the end attached to unit a";
  input Real v_a(unit = "m/s") "speed of the end attached to unit a";
  input Real x_b(unit = "m") "position of the end attached to unit b";
  input Real v_b(unit = "m/s") "speed of the end attached to unit b";
  input Real eta(unit = "1") "unit-variance white noise sample of the reading noise" annotation(__RehabSim(noise = "gaussian", period = T_sample));
  input Real f_held(unit = "N") "noisy force held since the last sample" annotation(__RehabSim(sample = f_noisy, period = T_sample));
  output Real f_lc(unit = "N") "force on unit a, positive pushing a towards +x (unit b gets -f_lc)";
  output Real f_meas(unit = "N") "load-cell reading: f_lc plus noise, sampled and held";
  Real f_noisy(unit = "N") "force plus reading noise, before sampling";
equation
  f_lc = k_lc * (x_b - x_a - l0) + d_lc * (v_b - v_a);
  f_noisy = f_lc + sigma_lc * eta;
  f_meas = f_held;
end LoadCell;
