within RehabSim;
model LuGreFriction "LuGre friction torque (Canudas de Wit et al. 1995) with Stribeck curve and speed-dependent bristle damping, rotational"
  parameter Real tau_c(unit = "N.m", min = 0) = 3e-3 "Coulomb friction torque (Table 1, fc)";
  parameter Real tau_s(unit = "N.m", min = 0) = 3e-3 "static (breakaway) friction torque; tau_s = tau_c gives no Stribeck effect";
  parameter Real w_s(unit = "rad/s", min = 1e-9) = 1.0 "Stribeck speed of the curve g(w) = tau_c + (tau_s - tau_c) exp(-(w/w_s)^2)";
  parameter Real sigma_0(unit = "N.m/rad", min = 0) = 200 "bristle stiffness (presliding deflection tau/sigma_0)";
  parameter Real sigma_1(unit = "N.m.s/rad", min = 0) = 0.117 "bristle (micro) damping at zero speed";
  parameter Real w_d(unit = "rad/s", min = 1e-9) = 0.1 "speed over which the bristle damping fades, sigma_1 exp(-(w/w_d)^2)";
  parameter Real sigma_2(unit = "N.m.s/rad", min = 0) = 1.6e-5 "viscous friction coefficient (Table 1, b)";
  parameter Real z0(unit = "rad") = 0 "initial bristle deflection";
  input Real w(unit = "rad/s") "sliding speed (motor speed)";
  output Real tau(unit = "N.m") "friction torque, opposing w";
  Real z(unit = "rad", start = z0, fixed = true, nominal = 3e-5) "average bristle deflection (LuGre internal state)";
equation
  der(z) = w - sigma_0 * abs(w) * z / max(tau_c + (tau_s - tau_c) * exp(-(w / w_s) ^ 2), 1e-12);
  tau = sigma_0 * z + sigma_1 * exp(-(w / w_d) ^ 2) * der(z) + sigma_2 * w;
end LuGreFriction;
