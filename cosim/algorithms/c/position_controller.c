/* position_controller.c: compiled step of cosim.algorithms.zero_force.PositionController.
 *
 * in = {x, x_ref, [v_ref if derivative_on_error], [v if use_velocity_input],
 *       [a_ref if feedforward_mass_kg > 0]}
 * out = {i_cmd, e}
 * The same operations in the same order as PositionController.step (Python's
 * min/max semantics for the saturation, NaN included).
 */
#include "cosim_kernel.h"

typedef struct {                 /* zero_force.PositionControllerParamsC */
    double Kp_N_per_m;
    double Kd_Ns_per_m;
    double Ki_N_per_ms;
    double feedforward_mass_kg;
    double use_velocity_input;
    double derivative_on_error;
    double saturate;
    double i_max_A;
    double Ts_s;
    double Kf_N_per_A;           /* force -> current */
} position_controller_params;

typedef struct {                 /* zero_force.PositionControllerStateC */
    double integral_ms;          /* integral of the error [m s] */
    double x_prev_m;
    double has_x_prev;
} position_controller_state;

int cosim_kernel_position_controller(const void *params, void *state, const double *in,
                                     double *out)
{
    const position_controller_params *p = params;
    position_controller_state *s = state;
    const double Kp = p->Kp_N_per_m, Kd = p->Kd_Ns_per_m, Ki = p->Ki_N_per_ms;
    const double ff = p->feedforward_mass_kg, Ts = p->Ts_s, Kf = p->Kf_N_per_A;
    const int use_v = p->use_velocity_input != 0.0, d_err = p->derivative_on_error != 0.0;
    const int sat = p->saturate != 0.0;
    int q = 2;
    const double x = in[0];
    const double e = in[1] - x;
    const double v_ref = d_err ? in[q++] : 0.0;
    double v;
    if (use_v) v = in[q++];
    else v = s->has_x_prev == 0.0 ? 0.0 : (x - s->x_prev_m) / Ts;
    s->x_prev_m = x; s->has_x_prev = 1.0;
    double force = Kp * e + Kd * (v_ref - v) + Ki * s->integral_ms;
    if (ff > 0) force += ff * in[q++];
    const double i_unsat = force / Kf;               /* drive.force_to_current */
    double i_cmd = i_unsat;
    if (sat) {                                       /* max(-lim, min(lim, value)) */
        const double lim = p->i_max_A;
        const double m = i_unsat < lim ? i_unsat : lim;
        i_cmd = m > -lim ? m : -lim;
    }
    if (i_cmd == i_unsat) s->integral_ms += e * Ts;  /* clamping anti-windup */
    out[0] = i_cmd;
    out[1] = e;
    return 0;
}
