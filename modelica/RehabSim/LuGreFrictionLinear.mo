within RehabSim;
model LuGreFrictionLinear "LuGre friction force (Canudas de Wit et al. 1995) with Stribeck curve and speed-dependent bristle damping, translational"
  parameter Real f_c(unit = "N", min = 0) = 1.0 "Coulomb friction force";
  parameter Real f_s(unit = "N", min = 0) = 1.0 "static (breakaway) friction force; f_s = f_c gives no Stribeck effect";
  parameter Real v_s(unit = "m/s", min = 1e-12) = 0.01 "Stribeck speed of the curve g(v) = f_c + (f_s - f_c) exp(-(v/v_s)^2)";
  parameter Real sigma_0(unit = "N/m", min = 0) = 1e6 "bristle stiffness (presliding deflection f/sigma_0)";
  parameter Real sigma_1(unit = "N.s/m", min = 0) = 2450 "bristle (micro) damping at zero speed";
  parameter Real v_d(unit = "m/s", min = 1e-12) = 1e-3 "speed over which the bristle damping fades, sigma_1 exp(-(v/v_d)^2)";
  parameter Real sigma_2(unit = "N.s/m", min = 0) = 2.0 "viscous friction coefficient";
  parameter Real z0(unit = "m") = 0 "initial bristle deflection";
  input Real v(unit = "m/s") "sliding speed";
  output Real f(unit = "N") "friction force, opposing v";
  Real z(unit = "m", start = z0, fixed = true, nominal = 1e-6) "average bristle deflection (LuGre internal state)";
equation
  der(z) = v - sigma_0 * abs(v) * z / max(f_c + (f_s - f_c) * exp(-(v / v_s) ^ 2), 1e-12);
  f = sigma_0 * z + sigma_1 * exp(-(v / v_d) ^ 2) * der(z) + sigma_2 * v;
end LuGreFrictionLinear;
