/* position_controller.c: compiled step of cosim.algorithms.zero_force.PositionController.
 *
 * p = {Kp_N_per_m, Kd_Ns_per_m, Ki_N_per_ms, feedforward_mass_kg, use_velocity_input,
 *      derivative_on_error, has_i_max, i_max_A, Ts_s, Kf_N_per_A}
 * s = {integral, x_prev, has_x_prev}
 * in = {x, x_ref, [v_ref if derivative_on_error], [v if use_velocity_input],
 *       [a_ref if feedforward_mass_kg > 0]}
 * out = {i_cmd, e}
 * The same operations in the same order as PositionController.step (Python's
 * min/max semantics for the saturation, NaN included).
 */
#include "cosim_kernel.h"

int cosim_kernel_position_controller(const double *p, double *s, const double *in, double *out)
{
    const double Kp = p[0], Kd = p[1], Ki = p[2], ff = p[3], Ts = p[8], Kf = p[9];
    const int use_v = p[4] != 0.0, d_err = p[5] != 0.0, sat = p[6] != 0.0;
    int q = 2;
    const double x = in[0];
    const double e = in[1] - x;
    const double v_ref = d_err ? in[q++] : 0.0;
    double v;
    if (use_v) v = in[q++];
    else v = s[2] == 0.0 ? 0.0 : (x - s[1]) / Ts;
    s[1] = x; s[2] = 1.0;
    double force = Kp * e + Kd * (v_ref - v) + Ki * s[0];
    if (ff > 0) force += ff * in[q++];
    const double i_unsat = force / Kf;               /* drive.force_to_current */
    double i_cmd = i_unsat;
    if (sat) {                                       /* max(-lim, min(lim, value)) */
        const double lim = p[7];
        const double m = i_unsat < lim ? i_unsat : lim;
        i_cmd = m > -lim ? m : -lim;
    }
    if (i_cmd == i_unsat) s[0] += e * Ts;            /* clamping anti-windup */
    out[0] = i_cmd;
    out[1] = e;
    return 0;
}
