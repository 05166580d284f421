within RehabSim.Gap;
model CurrentDriver "Current driver between the command and the motor current: transport delay (Pade (2,3) approximant), current limit, first-order current loop; each off by default (ideal driver: current = command)"
  parameter Real T_d(unit = "s", min = 0) = 0 "actuator_delay: transport delay from command to current (0: none)";
  parameter Real i_max(unit = "A", min = 0) = 1000 "current_saturation: current limit of the driver (default 1000 A: never reached)";
  parameter Real T_cl(unit = "s", min = 0) = 0 "current_loop_lag: time constant of the closed current loop, 1/(2 pi bandwidth) (0: infinite bandwidth)";
  parameter Real i_hold(unit = "A") = 0 "command held before t = 0: the delay and lag states start in equilibrium with it";
  input Real i_cmd(unit = "A") "current command (zero-order hold)";
  output Real i(unit = "A") "motor current";
  Real i_d(unit = "A") "command after the transport delay";
  Real i_s(unit = "A") "delayed command clipped at the current limit";
  Real q1(unit = "A", start = i_hold, fixed = true) "Pade delay state 1 (equals the delayed command at equilibrium)";
  Real q2(unit = "A", start = 0, fixed = true) "Pade delay state 2 (T_d times the rate of q1)";
  Real q3(unit = "A", start = 0, fixed = true) "Pade delay state 3 (T_d times the rate of q2)";
  Real i_l(unit = "A", start = min(max(i_hold, -i_max), i_max), fixed = true) "current-loop lag state";
equation
  // exp(-s T) ~ (60 - 24 sT + 3 (sT)^2) / (60 + 36 sT + 9 (sT)^2 + (sT)^3), the (2,3) Pade
  // approximant: strictly proper, so a command step does not produce the instantaneous
  // reversed torque of the (n,n) approximants; controllable form in the time t/T_d
  der(q1) = if T_d > 0 then q2 / max(T_d, 1e-12) else 0;
  der(q2) = if T_d > 0 then q3 / max(T_d, 1e-12) else 0;
  der(q3) = if T_d > 0 then (60 * i_cmd - 60 * q1 - 36 * q2 - 9 * q3) / max(T_d, 1e-12) else 0;
  i_d = if T_d > 0 then q1 - 0.4 * q2 + 0.05 * q3 else i_cmd;
  i_s = min(max(i_d, -i_max), i_max);
  der(i_l) = if T_cl > 0 then (i_s - i_l) / max(T_cl, 1e-12) else 0;
  i = if T_cl > 0 then i_l else i_s;
end CurrentDriver;
