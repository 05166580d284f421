/* zero_force.c: compiled step of cosim.algorithms.zero_force.ZeroForceController, the
 * proportional zero-force controller of thesis Fig. 28 (Sec. 2.5.3). Same arithmetic in
 * the same order as ZeroForceController.step (bit-identical, tests/test_kernels.py).
 *
 * p: [0] Kf_p [N/N]  [1] Kf = Kt 2 pi/lead [N/A]  [2] enabled  [3] use_dob
 *    [4] use_force_reference  [5] saturate  [6] i_max [A]
 * s: [0] f_cntr [N]
 * in: f_lc or f_hat [N], then i_dob [A] if use_dob, then f_r [N] if use_force_reference
 * out: i_cmd [A], f_cntr [N]
 */
#include "cosim_kernel.h"

int cosim_kernel_zero_force(const double *p, double *s, const double *in, double *out)
{
    int j = 1;
    double f_int = in[0];
    double i_cmp = p[3] != 0.0 ? in[j++] : 0.0;
    double f_r = p[4] != 0.0 ? in[j] : 0.0;
    /* Fig. 28: f_cntr = C(s) (f_r - f_int) with C = Kf_p (proportional) */
    s[0] = p[2] != 0.0 ? p[0] * (f_r - f_int) : 0.0;
    double i_c = s[0] / p[1];                                /* F -> torque -> current */
    double i_tot = i_c + i_cmp;                              /* eq. 5: I_tot = I_c + I_cmp */
    if (p[5] != 0.0) {                       /* max(-limit, min(limit, value)) as in Python */
        double m = i_tot < p[6] ? i_tot : p[6];
        i_tot = m > -p[6] ? m : -p[6];
    }
    out[0] = i_tot;
    out[1] = s[0];
    return 0;
}
