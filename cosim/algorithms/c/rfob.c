/* rfob.c: compiled step of cosim.algorithms.dob.RFOB, the reaction force observer of
 * thesis eq. 10 with the identified ZOH model (eq. 39-40), see dob.py. Same arithmetic
 * in the same order as RFOB.step (bit-identical, tests/test_kernels.py).
 *
 * in: i_cmd [A], w [rad/s]
 * out: tau_ext_hat [N m], f_ext_hat [N], f_int_hat [N], tau_raw [N m]
 */
#include <math.h>
#include "cosim_kernel.h"

#define PI 3.141592653589793    /* math.pi, the same double */

typedef struct {                 /* dob.RFOBParamsC */
    double Ts_s;
    double pole;                 /* exp(-g_RFOB Ts) */
    double fc_Nm;                /* identified Coulomb friction */
    double w_eps_rad_s;          /* half-width of the smoothed sign's linear zone */
    double a1;                   /* exp(-Ts b/J), eq. 39 */
    double b0_rad_s_per_Nm;      /* (1 - a1)/b, eq. 39 */
    double Kt_Nm_per_A;          /* identified torque constant */
    double tau_load_Nm;          /* known load torque */
    double lead_m;               /* screw lead per revolution */
    double i_cmd_is_previous;    /* 1: i_cmd is the current held over the last interval */
} rfob_params;

typedef struct {                 /* dob.RFOBStateC */
    double tau_hat_Nm;
    double tau_raw_Nm;
    double w_prev_rad_s;
    double has_w_prev;
    double i_prev_A;
    double has_i_prev;
} rfob_state;

/* dob.smooth_sign: clip(w/w_eps, -1, 1) as max(-1, min(1, w/w_eps)) in Python's
 * argument order; the plain sign if w_eps <= 0 */
static double smooth_sign(double w, double w_eps)
{
    if (w_eps <= 0.0)
        return (double)((w > 0.0) - (w < 0.0));
    double q = w / w_eps;
    double m = q < 1.0 ? q : 1.0;
    return m > -1.0 ? m : -1.0;
}

int cosim_kernel_rfob(const void *params, void *state, const double *in, double *out)
{
    const rfob_params *p = params;
    rfob_state *s = state;
    double i_in = in[0], w = in[1];
    int prev = p->i_cmd_is_previous != 0.0;
    int has_held = prev || s->has_i_prev != 0.0;
    double i_held = prev ? i_in : s->i_prev_A;
    if (s->has_w_prev != 0.0 && has_held) {
        double w_mid = 0.5 * (w + s->w_prev_rad_s);
        double tau_f = p->fc_Nm * smooth_sign(w_mid, p->w_eps_rad_s);   /* Coulomb part of tau_f */
        /* eq. 10 (external = -reaction), inertia + viscous via the ZOH model eq. 39-40 */
        s->tau_raw_Nm = (w - p->a1 * s->w_prev_rad_s) / p->b0_rad_s_per_Nm
                        - p->Kt_Nm_per_A * i_held + tau_f + p->tau_load_Nm;
        s->tau_hat_Nm = p->pole * s->tau_hat_Nm + (1.0 - p->pole) * s->tau_raw_Nm;  /* g/(s+g) */
    }
    s->w_prev_rad_s = w;
    s->has_w_prev = 1.0;
    s->i_prev_A = i_in;
    s->has_i_prev = 1.0;
    double f_ext = s->tau_hat_Nm * 2.0 * PI / p->lead_m;    /* tau = f lead/(2 pi) */
    out[0] = s->tau_hat_Nm;
    out[1] = f_ext;
    out[2] = -f_ext;
    out[3] = s->tau_raw_Nm;
    return 0;
}
