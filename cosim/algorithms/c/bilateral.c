/* bilateral.c: compiled step of cosim.algorithms.bilateral.BilateralController, the
 * acceleration-based bilateral controller of thesis eq. 54-55 (structure of [74, 91]).
 * Same arithmetic in the same order as its step (bit-identical, tests/test_kernels.py).
 *
 * p: [0] Kp [1/s^2]  [1] Kv [1/s]  [2] Cf [N/N]  [3] Dc [1/s]  [4] m_n [kg]
 *    [5] Kf [N/A]  [6] use_dob  [7] saturate  [8] i_max [A]
 * s: [0] 1 once a step has run, [1..6] the last outputs (BilateralController.last)
 * in: x_m, x_s [m], v_m, v_s [m/s], f_m, f_s [N], then i_dob_m, i_dob_s [A] if use_dob
 * out: i_m, i_s [A], acc_ref_m, acc_ref_s [m/s^2], x_d [m], f_c [N]
 */
#include "cosim_kernel.h"

static double saturate(double v, const double *p)
{
    if (p[7] == 0.0)
        return v;
    double m = v < p[8] ? v : p[8];        /* max(-limit, min(limit, value)) */
    return m > -p[8] ? m : -p[8];
}

int cosim_kernel_bilateral(const double *p, double *s, const double *in, double *out)
{
    double x_m = in[0], x_s = in[1], v_m = in[2], v_s = in[3], f_m = in[4], f_s = in[5];
    double m_n = p[4];
    /* modal decomposition (Hadamard) */
    double x_d = x_m - x_s, v_d = v_m - v_s;                   /* eq. 54 quantity */
    double v_c = v_m + v_s;
    double f_c = f_m + f_s;                                    /* eq. 55 quantity */
    /* differential mode: position servo on x_m - x_s = 0 (eq. 54) */
    double a_d = p[0] * (0.0 - x_d) + p[1] * (0.0 - v_d);
    /* common mode: force servo on f_m + f_s = 0 (eq. 55) */
    double a_c = p[2] / m_n * (0.0 - f_c) - p[3] * v_c;
    /* inverse Hadamard */
    double a_m = 0.5 * (a_c + a_d);
    double a_s = 0.5 * (a_c - a_d);
    /* acceleration control through the nominal plant + DOB (eq. 5, 7) */
    double i_m = m_n * a_m / p[5];
    double i_s = m_n * a_s / p[5];
    if (p[6] != 0.0) {
        i_m += in[6];
        i_s += in[7];
    }
    out[0] = saturate(i_m, p);
    out[1] = saturate(i_s, p);
    out[2] = a_m; out[3] = a_s; out[4] = x_d; out[5] = f_c;
    s[0] = 1.0;
    for (int j = 0; j < 6; j++)
        s[1 + j] = out[j];
    return 0;
}
