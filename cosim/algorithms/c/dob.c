/* dob.c: compiled step of cosim.algorithms.dob.DOB, the disturbance observer of thesis
 * Sec. 2.1.2 (eq. 2-7) on the exact ZOH model of the sampled plant (see dob.py).
 * Same arithmetic in the same order as DOB.step (bit-identical, tests/test_kernels.py).
 *
 * in: i_cmd [A], w [rad/s]
 * out: tau_dis_hat [N m], i_cmp [A], then i_tot [A] unless i_cmd_is_total_previous;
 *      then d_raw [N m]
 */
#include "cosim_kernel.h"

typedef struct {                 /* dob.DOBParamsC */
    double Ktn_Nm_per_A;         /* nominal torque constant */
    double Jn_kg_m2;             /* nominal inertia */
    double Ts_s;                 /* sampling time */
    double pole;                 /* exp(-g_DOB Ts) */
    double i_cmd_is_total_previous;   /* 1: i_cmd is the total current held over the last interval */
} dob_params;

typedef struct {                 /* dob.DOBStateC */
    double tau_hat_Nm;           /* filtered disturbance estimate */
    double d_raw_Nm;             /* unfiltered disturbance of the last interval */
    double w_prev_rad_s;         /* w at the previous tick */
    double has_w_prev;
    double i_tot_prev_A;         /* total current issued at the previous tick */
    double has_i_tot_prev;
} dob_state;

int cosim_kernel_dob(const void *params, void *state, const double *in, double *out)
{
    const dob_params *p = params;
    dob_state *s = state;
    double i_in = in[0], w = in[1];
    int total_prev = p->i_cmd_is_total_previous != 0.0;
    int has_held = total_prev || s->has_i_tot_prev != 0.0;
    double i_held = total_prev ? i_in : s->i_tot_prev_A;
    if (s->has_w_prev != 0.0 && has_held) {
        /* eq. 2 over the last ZOH interval: Kt_n I_tot - J_n w' */
        s->d_raw_Nm = p->Ktn_Nm_per_A * i_held - p->Jn_kg_m2 * (w - s->w_prev_rad_s) / p->Ts_s;
        /* eq. 6: ZOH equivalent of g_DOB/(s + g_DOB) */
        s->tau_hat_Nm = p->pole * s->tau_hat_Nm + (1.0 - p->pole) * s->d_raw_Nm;
    }
    double i_cmp = s->tau_hat_Nm / p->Ktn_Nm_per_A;                      /* eq. 7 */
    s->w_prev_rad_s = w;
    s->has_w_prev = 1.0;
    out[0] = s->tau_hat_Nm;
    out[1] = i_cmp;
    if (!total_prev) {
        double i_tot = i_in + i_cmp;                                     /* eq. 5 */
        s->i_tot_prev_A = i_tot;
        s->has_i_tot_prev = 1.0;
        out[2] = i_tot;
        out[3] = s->d_raw_Nm;
    } else {
        out[2] = s->d_raw_Nm;
    }
    return 0;
}
