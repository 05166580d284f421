within RehabSim.Emps;
model EmpsDrive "Drive between the commanded force and the force on the axis: transport delay (Pade (2,3) approximant) then first-order lag; both off by default (ideal drive: force = command)"
  parameter Real T_d(unit = "s", min = 0) = 0 "actuator_delay: transport delay from command to force (0: none)";
  parameter Real T_l(unit = "s", min = 0) = 0 "current_loop_lag: time constant of the drive's closed current loop, 1/(2 pi bandwidth) (0: infinite bandwidth)";
  parameter Real f0(unit = "N") = 0 "command held before t = 0: the delay and lag states start in equilibrium with it";
  input Real f_in(unit = "N") "commanded force (zero-order hold)";
  output Real f_out(unit = "N") "force the drive applies to the axis";
  Real f_d(unit = "N") "command after the transport delay";
  Real p1(unit = "N", start = f0, fixed = true) "Pade delay state 1 (equals the delayed command at equilibrium)";
  Real p2(unit = "N", start = 0, fixed = true) "Pade delay state 2 (T_d times the rate of p1)";
  Real p3(unit = "N", start = 0, fixed = true) "Pade delay state 3 (T_d times the rate of p2)";
  Real f_l(unit = "N", start = f0, fixed = true) "drive lag state";
equation
  // exp(-s T) ~ (60 - 24 sT + 3 (sT)^2) / (60 + 36 sT + 9 (sT)^2 + (sT)^3): strictly proper,
  // so a force pulse (PULSES trial) does not give the instantaneous reversed force of an
  // (n,n) approximant; controllable form in the time t/T_d
  der(p1) = if T_d > 0 then p2 / max(T_d, 1e-12) else 0;
  der(p2) = if T_d > 0 then p3 / max(T_d, 1e-12) else 0;
  der(p3) = if T_d > 0 then (60 * f_in - 60 * p1 - 36 * p2 - 9 * p3) / max(T_d, 1e-12) else 0;
  f_d = if T_d > 0 then p1 - 0.4 * p2 + 0.05 * p3 else f_in;
  der(f_l) = if T_l > 0 then (f_d - f_l) / max(T_l, 1e-12) else 0;
  f_out = if T_l > 0 then f_l else f_d;
end EmpsDrive;
