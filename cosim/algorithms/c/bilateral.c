/* bilateral.c: compiled step of cosim.algorithms.bilateral.BilateralController, the
 * acceleration-based bilateral controller of thesis eq. 54-55 (structure of [74, 91]).
 * Same arithmetic in the same order as its step (bit-identical, tests/test_kernels.py).
 *
 * in: x_m, x_s [m], v_m, v_s [m/s], f_m, f_s [N], then i_dob_m, i_dob_s [A] if use_dob
 * out: i_m, i_s [A], acc_ref_m, acc_ref_s [m/s^2], x_d [m], f_c [N]
 */
#include "cosim_kernel.h"

typedef struct {                 /* bilateral.BilateralParamsC */
    double Kp_per_s2;            /* differential-mode position gain */
    double Kv_per_s;             /* differential-mode velocity gain */
    double Cf_N_per_N;           /* common-mode force gain */
    double Dc_per_s;             /* common-mode damping */
    double m_n_kg;               /* nominal mass equivalent */
    double Kf_N_per_A;           /* force constant */
    double use_dob;
    double saturate;
    double i_max_A;
} bilateral_params;

typedef struct {                 /* bilateral.BilateralStateC */
    double has_last;             /* 1 once a step has run */
    double last[6];              /* the last outputs (BilateralController.last), in out's order */
} bilateral_state;

static double saturate(double v, const bilateral_params *p)
{
    if (p->saturate == 0.0)
        return v;
    double m = v < p->i_max_A ? v : p->i_max_A;        /* max(-limit, min(limit, value)) */
    return m > -p->i_max_A ? m : -p->i_max_A;
}

int cosim_kernel_bilateral(const void *params, void *state, const double *in, double *out)
{
    const bilateral_params *p = params;
    bilateral_state *s = state;
    double x_m = in[0], x_s = in[1], v_m = in[2], v_s = in[3], f_m = in[4], f_s = in[5];
    double m_n = p->m_n_kg;
    /* modal decomposition (Hadamard) */
    double x_d = x_m - x_s, v_d = v_m - v_s;                   /* eq. 54 quantity */
    double v_c = v_m + v_s;
    double f_c = f_m + f_s;                                    /* eq. 55 quantity */
    /* differential mode: position servo on x_m - x_s = 0 (eq. 54) */
    double a_d = p->Kp_per_s2 * (0.0 - x_d) + p->Kv_per_s * (0.0 - v_d);
    /* common mode: force servo on f_m + f_s = 0 (eq. 55) */
    double a_c = p->Cf_N_per_N / m_n * (0.0 - f_c) - p->Dc_per_s * v_c;
    /* inverse Hadamard */
    double a_m = 0.5 * (a_c + a_d);
    double a_s = 0.5 * (a_c - a_d);
    /* acceleration control through the nominal plant + DOB (eq. 5, 7) */
    double i_m = m_n * a_m / p->Kf_N_per_A;
    double i_s = m_n * a_s / p->Kf_N_per_A;
    if (p->use_dob != 0.0) {
        i_m += in[6];
        i_s += in[7];
    }
    out[0] = saturate(i_m, p);
    out[1] = saturate(i_s, p);
    out[2] = a_m; out[3] = a_s; out[4] = x_d; out[5] = f_c;
    s->has_last = 1.0;
    for (int j = 0; j < 6; j++)
        s->last[j] = out[j];
    return 0;
}
