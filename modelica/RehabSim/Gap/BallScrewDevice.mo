within RehabSim.Gap;
model BallScrewDevice "Ball-screw device of record (RehabSim.BallScrewUnit: motor + screw, LuGre friction, current input) with every effect of the gap-diagnosis catalogue as a parameter that is off by default; two-body (motor+screw | nut+handle+accelerometer) when backlash or transmission compliance is on"
  // ---- nominal device (RehabSim.BallScrewUnit, thesis Sec. 2.4, Table 1)
  parameter Real J(unit = "kg.m2", min = 0) = RehabSim.Table1.J "total inertia at the motor shaft, nut and handle included (Table 1)";
  parameter Real b(unit = "N.m.s/rad", min = 0) = 1.6e-5 "viscous friction coefficient, mean of both directions (Table 1)";
  parameter Real fc(unit = "N.m", min = 0) = 3e-3 "Coulomb friction torque, mean of both directions (Table 1)";
  parameter Real Kt(unit = "N.m/A", min = 0) = RehabSim.Table1.Kt "motor torque constant (Table 1, 60.3 mNm/A)";
  parameter Real lead(unit = "m", min = 0) = 0.01 "ball screw lead: nut travel per motor revolution (Table 1)";
  parameter Real r(unit = "m/rad") = lead / (2 * 3.141592653589793) "transmission ratio x/theta = lead/(2 pi)";
  parameter Real sigma0(unit = "N.m/rad", min = 0) = 200 "LuGre bristle stiffness (as RehabSim.BallScrewUnit)";
  parameter Real sigma1(unit = "N.m.s/rad", min = 0) = 0.117 "LuGre bristle damping at rest (as RehabSim.BallScrewUnit)";
  parameter Real wd(unit = "rad/s", min = 1e-9) = 0.1 "speed over which the bristle damping fades (as RehabSim.BallScrewUnit)";
  parameter Real m_n(unit = "kg", min = 1e-6) = 0.2 "mass of nut + handle + accelerometer (a share of J: m_n r^2 = 5e-7 kg m2; not in the thesis, assumed); used by the two-body transmission";
  parameter Real delta_enc(unit = "rad", min = 0) = RehabSim.Table1.delta_enc "encoder resolution (Table 1)";
  parameter Real theta0(unit = "rad") = 0 "initial motor angle";
  parameter Real w0(unit = "rad/s") = 0 "initial motor speed";
  parameter Real i0(unit = "A") = 0 "current command held before the start (delay and lag states start in equilibrium with it)";
  parameter Real g_n(unit = "m/s2") = 9.80665 "standard gravity";
  // ---- stribeck_friction
  parameter Real dfs(unit = "N.m") = 0 "stribeck_friction: static (breakaway) minus Coulomb torque, fs - fc";
  parameter Real ws(unit = "rad/s", min = 1e-9) = 1.0 "stribeck_friction: Stribeck speed (motor side)";
  // ---- asymmetric_friction
  parameter Real dfc(unit = "N.m") = 0 "asymmetric_friction: Coulomb torque is fc + dfc moving towards +x, fc - dfc towards -x";
  parameter Real db(unit = "N.m.s/rad") = 0 "asymmetric_friction: viscous coefficient is b + db towards +x, b - db towards -x";
  // ---- position_dependent_friction
  parameter Real kfx(unit = "N.m/m") = 0 "position_dependent_friction: Coulomb torque gradient along the travel (preload)";
  parameter Real dfp(unit = "N.m") = 0 "position_dependent_friction: amplitude of the Coulomb torque varying periodically along the travel";
  parameter Real lp(unit = "m", min = 1e-6) = 0.04 "position_dependent_friction: period of that variation along the travel";
  parameter Real php(unit = "rad") = 0 "position_dependent_friction: phase of that variation at x = 0";
  // ---- cogging_torque
  parameter Real A_cog(unit = "N.m") = 0 "cogging_torque: amplitude of the torque ripple";
  parameter Real n_cog(unit = "1", min = 0) = 6 "cogging_torque: ripple periods per motor revolution";
  parameter Real phi_cog(unit = "rad") = 0 "cogging_torque: phase of the ripple at theta = 0";
  // ---- backlash and transmission_compliance (two-body transmission)
  parameter Real backlash(unit = "m", min = 0) = 0 "backlash: total axial play between screw and nut (0: none)";
  parameter Real c_tr(unit = "m/N", min = 0) = 0 "transmission_compliance: axial compliance 1/k between screw and nut (0: rigid)";
  parameter Real zeta_tr(unit = "1", min = 0) = 0.05 "damping ratio of the nut on the transmission stiffness, d = 2 zeta sqrt(k m_n)";
  parameter Real k_bl(unit = "N/m", min = 0) = 1e7 "contact stiffness in the backlash when c_tr = 0 (steel ball contact)";
  parameter Real k_tr(unit = "N/m") = if c_tr > 0 then 1 / max(c_tr, 1e-300) else k_bl "transmission stiffness in two-body mode";
  parameter Real d_tr(unit = "N.s/m") = 2 * zeta_tr * sqrt(k_tr * m_n) "transmission damping in two-body mode";
  parameter Real h_bl(unit = "m") = backlash / 2 "half play: the nut is free while |r theta - x| < h_bl";
  // ---- actuator_delay, current_loop_lag, current_saturation (current driver)
  parameter Real Td(unit = "s", min = 0) = 0 "actuator_delay: transport delay from current command to torque";
  parameter Real Tcl(unit = "s", min = 0) = 0 "current_loop_lag: time constant of the current loop";
  parameter Real i_lim(unit = "A", min = 0) = 1000 "current_saturation: driver current limit (1000 A: never reached)";
  // ---- accel_scale_error, accel_bias_drift
  parameter Real ds_acc(unit = "1") = 0 "accel_scale_error: relative scale-factor error of the accelerometer";
  parameter Real psi_acc(unit = "rad") = 0 "accel_scale_error: misalignment of the sensing axis from the screw axis, in the vertical plane";
  parameter Real b0_acc(unit = "m/s2") = 0 "accel_bias_drift: accelerometer bias at t = 0";
  parameter Real db_acc(unit = "m/s2") = 0 "accel_bias_drift: bias change of the thermal drift, b(t) = b0 + db (1 - exp(-t/T))";
  parameter Real T_acc(unit = "s", min = 1e-6) = 60 "accel_bias_drift: thermal time constant of the drift";
  // ---- gravity_load
  parameter Real alpha(unit = "rad") = 0 "gravity_load: tilt of the axis, +x raised by alpha";
  parameter Real kappa(unit = "rad/m") = 0 "gravity_load: change of the local tilt along the travel (sagging or curved guide)";
  parameter Real m_g(unit = "kg", min = 0) = 0.2 "gravity_load: mass that gravity pulls along the axis (nut + handle)";
  input Real i_cmd(unit = "A") "motor current command (zero-order hold)";
  input Real f_ext(unit = "N") "external force on the handle along +x (human, load cell)";
  output Real theta(unit = "rad", start = theta0, fixed = true) "motor angle (unquantised)";
  output Real w(unit = "rad/s") "motor speed";
  output Real x(unit = "m") "nut (handle) position";
  output Real v(unit = "m/s") "nut (handle) speed";
  output Real a(unit = "m/s2") "nut (handle) acceleration";
  output Real acc_spec(unit = "m/s2") "specific force along the accelerometer axis: a, gravity component and sensor effects (no noise)";
  output Real tau_m(unit = "N.m") "motor torque actually applied, Kt i plus cogging";
  output Real i_act(unit = "A") "motor current after the driver (delay, limit, lag)";
  output Real tau_f(unit = "N.m") "friction torque (LuGre, including viscous), opposing w";
  output Real f_tr(unit = "N") "force of the screw on the nut (two-body mode; 0 when rigid)";
  output Real f_g(unit = "N") "gravity force on the nut along +x";
  output Real theta_enc(unit = "rad") "encoder reading: theta rounded to the encoder resolution";
  Real xn(unit = "m", start = r * theta0, fixed = true) "nut position, two-body mode (frozen when rigid)";
  Real vn(unit = "m/s", start = r * w0, fixed = true) "nut speed, two-body mode (frozen when rigid)";
  Real dl(unit = "m") "transmission deflection r theta - xn (two-body mode)";
  RehabSim.Gap.LuGreFrictionGap friction(tau_c = fc, sigma_2 = b, sigma_0 = sigma0, sigma_1 = sigma1, w_d = wd, d_s = dfs, w_s = ws, d_c = dfc, d_v = db, k_x = kfx, d_p = dfp, l_p = lp, phi_p = php, w(start = w0, fixed = true)) "friction of motor, screw and nut, referred to the motor shaft";
  RehabSim.Gap.CurrentDriver power_stage(T_d = Td, T_cl = Tcl, i_max = i_lim, i_hold = i0) "current driver (power stage)";
equation
  power_stage.i_cmd = i_cmd;
  i_act = power_stage.i;
  friction.x = r * theta;
  tau_f = friction.tau;
  tau_m = Kt * power_stage.i + A_cog * sin(n_cog * theta + phi_cog);
  f_g = -m_g * g_n * sin(alpha + kappa * x);
  dl = r * theta - xn;
  // screw-on-nut force: linear spring-damper, or a dead zone of half width h_bl whose
  // contact can push but never pull (MSL ElastoBacklash); zero in rigid mode
  f_tr = if backlash > 0 then (if dl > h_bl then max(k_tr * (dl - h_bl) + d_tr * (r * friction.w - vn), 0) elseif dl < -h_bl then min(k_tr * (dl + h_bl) + d_tr * (r * friction.w - vn), 0) else 0) elseif c_tr > 0 then k_tr * dl + d_tr * (r * friction.w - vn) else 0;
  der(theta) = friction.w;
  // rigid: eq. of BallScrewUnit; two-body: the motor side keeps J - m_n r^2
  (if backlash > 0 or c_tr > 0 then J - m_n * r ^ 2 else J) * der(friction.w) = tau_m - friction.tau + (if backlash > 0 or c_tr > 0 then -r * f_tr else r * (f_ext + f_g));
  der(xn) = if backlash > 0 or c_tr > 0 then vn else 0;
  m_n * der(vn) = if backlash > 0 or c_tr > 0 then f_tr + f_ext + f_g else 0;
  w = friction.w;
  x = if backlash > 0 or c_tr > 0 then xn else r * theta;
  v = if backlash > 0 or c_tr > 0 then vn else r * friction.w;
  a = if backlash > 0 or c_tr > 0 then der(vn) else r * der(friction.w);
  // specific force seen by an axis rotated by psi_acc: (a + g sin(tilt)) cos(psi) + g cos(tilt) sin(psi)
  acc_spec = (1 + ds_acc) * (a * cos(psi_acc) + g_n * sin(alpha + kappa * x + psi_acc)) + b0_acc + db_acc * (1 - exp(-time / T_acc));
  theta_enc = delta_enc * floor(theta / delta_enc + 0.5);
end BallScrewDevice;
