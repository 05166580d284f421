within RehabSim.Emps;
model EmpsFriction "Friction force of the EMPS axis: viscous + smoothed Coulomb (tanh), with optional direction asymmetry, Stribeck bump and position-dependent Coulomb level (all off by default)"
  parameter Real F_v(unit = "N.s/m", min = 0) = 203.5034 "viscous friction coefficient (publication, symmetric IDIM-LS)";
  parameter Real F_c(unit = "N", min = 0) = 20.3935 "Coulomb friction force (publication, symmetric IDIM-LS)";
  parameter Real v_e(unit = "m/s", min = 1e-9) = 1e-4 "speed scale of the smoothed sign tanh(v/v_e) that replaces sign(v)";
  parameter Real dF_v(unit = "N.s/m") = 0 "asymmetric_friction: viscous coefficient is F_v + dF_v for v > 0 and F_v - dF_v for v < 0";
  parameter Real dF_c(unit = "N") = 0 "asymmetric_friction: Coulomb force is F_c + dF_c for v > 0 and F_c - dF_c for v < 0";
  parameter Real F_s(unit = "N") = 0 "stribeck_friction: static friction above Coulomb, F_s exp(-(v/v_s)^2) sign(v)";
  parameter Real v_s(unit = "m/s", min = 1e-9) = 0.01 "stribeck_friction: Stribeck speed";
  parameter Real L_p(unit = "m", min = 1e-9) = 0.5 "position_dependent_friction: period of the first harmonic along the travel";
  parameter Real a_1(unit = "1") = 0 "position_dependent_friction: relative Coulomb variation, cos(2 pi x/L_p) coefficient";
  parameter Real b_1(unit = "1") = 0 "position_dependent_friction: relative Coulomb variation, sin(2 pi x/L_p) coefficient";
  parameter Real a_2(unit = "1") = 0 "position_dependent_friction: relative Coulomb variation, cos(4 pi x/L_p) coefficient";
  parameter Real b_2(unit = "1") = 0 "position_dependent_friction: relative Coulomb variation, sin(4 pi x/L_p) coefficient";
  input Real v(unit = "m/s") "sliding speed";
  input Real x(unit = "m") "position along the travel";
  output Real f(unit = "N") "friction force, opposing v";
equation
  f = (F_v + dF_v * tanh(v / v_e)) * v
      + (F_c * (1 + a_1 * cos(6.283185307179586 * x / L_p) + b_1 * sin(6.283185307179586 * x / L_p)
                  + a_2 * cos(12.566370614359172 * x / L_p) + b_2 * sin(12.566370614359172 * x / L_p))
         + dF_c * tanh(v / v_e)) * tanh(v / v_e)
      + F_s * exp(-(v / v_s) ^ 2) * tanh(v / v_e);
end EmpsFriction;
