within RehabSim.Gap;
model LuGreFrictionGap "LuGre friction torque of RehabSim.LuGreFriction with the catalogue's friction effects: Stribeck excess, direction asymmetry, position dependence (gradient + periodic) (all off by default)"
  parameter Real tau_c(unit = "N.m", min = 0) = 3e-3 "mean Coulomb friction torque (Table 1, fc)";
  parameter Real sigma_2(unit = "N.m.s/rad", min = 0) = 1.6e-5 "mean viscous friction coefficient (Table 1, b)";
  parameter Real sigma_0(unit = "N.m/rad", min = 0) = 200 "bristle stiffness (presliding deflection tau/sigma_0)";
  parameter Real sigma_1(unit = "N.m.s/rad", min = 0) = 0.117 "bristle (micro) damping at zero speed";
  parameter Real w_d(unit = "rad/s", min = 1e-9) = 0.1 "speed over which the bristle damping fades, sigma_1 exp(-(w/w_d)^2)";
  parameter Real d_s(unit = "N.m") = 0 "stribeck_friction: static minus Coulomb torque, fs - fc (0: no Stribeck effect)";
  parameter Real w_s(unit = "rad/s", min = 1e-9) = 1.0 "stribeck_friction: Stribeck speed of g(w) = fc + d_s exp(-(w/w_s)^2)";
  parameter Real d_c(unit = "N.m") = 0 "asymmetric_friction: half difference of the Coulomb torques, fc(+) = tau_c + d_c, fc(-) = tau_c - d_c";
  parameter Real d_v(unit = "N.m.s/rad") = 0 "asymmetric_friction: half difference of the viscous coefficients, b(+) = sigma_2 + d_v, b(-) = sigma_2 - d_v";
  parameter Real k_x(unit = "N.m/m") = 0 "position_dependent_friction: Coulomb torque gradient along the travel (nut preload varying along the screw)";
  parameter Real d_p(unit = "N.m") = 0 "position_dependent_friction: amplitude of the Coulomb torque varying periodically along the screw (preload, lead error, wear pattern)";
  parameter Real l_p(unit = "m", min = 1e-6) = 0.04 "position_dependent_friction: period of that variation along the travel";
  parameter Real phi_p(unit = "rad") = 0 "position_dependent_friction: phase of that variation at x = 0";
  parameter Real z0(unit = "rad") = 0 "initial bristle deflection";
  input Real w(unit = "rad/s") "sliding speed (motor speed)";
  input Real x(unit = "m") "nut position along the screw, x = r theta";
  output Real tau(unit = "N.m") "friction torque, opposing w";
  Real z(unit = "rad", start = z0, fixed = true, nominal = 3e-5) "average bristle deflection (LuGre internal state)";
equation
  // g(w, x): sliding friction level; sign(w) switches it by direction (harmless at w = 0,
  // where |w| multiplies it), floored so a large negative asymmetry cannot divide by zero
  der(z) = w - sigma_0 * abs(w) * z / max(tau_c + d_c * sign(w) + k_x * x + d_p * sin(6.283185307179586 * x / l_p + phi_p) + d_s * exp(-(w / w_s) ^ 2), 1e-12);
  tau = sigma_0 * z + sigma_1 * exp(-(w / w_d) ^ 2) * der(z) + sigma_2 * w + d_v * abs(w);
end LuGreFrictionGap;
