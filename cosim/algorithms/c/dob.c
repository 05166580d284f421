/* dob.c: compiled step of cosim.algorithms.dob.DOB, the disturbance observer of thesis
 * Sec. 2.1.2 (eq. 2-7) on the exact ZOH model of the sampled plant (see dob.py).
 * Same arithmetic in the same order as DOB.step (bit-identical, tests/test_kernels.py).
 *
 * p: [0] Kt_n [N m/A]  [1] J_n [kg m^2]  [2] Ts [s]  [3] pole exp(-g Ts)
 *    [4] 1 = i_cmd is the total current held over the last interval
 * s: [0] tau_hat [N m]  [1] d_raw [N m]  [2] w_k-1 [rad/s]  [3] has w_k-1
 *    [4] I_tot,k-1 [A]  [5] has I_tot,k-1
 * in: i_cmd [A], w [rad/s]
 * out: tau_dis_hat [N m], i_cmp [A], then i_tot [A] unless p[4]; then d_raw [N m]
 */
#include "cosim_kernel.h"

int cosim_kernel_dob(const double *p, double *s, const double *in, double *out)
{
    double i_in = in[0], w = in[1];
    int total_prev = p[4] != 0.0;
    int has_held = total_prev || s[5] != 0.0;
    double i_held = total_prev ? i_in : s[4];
    if (s[3] != 0.0 && has_held) {
        /* eq. 2 over the last ZOH interval: Kt_n I_tot - J_n w' */
        s[1] = p[0] * i_held - p[1] * (w - s[2]) / p[2];
        /* eq. 6: ZOH equivalent of g_DOB/(s + g_DOB) */
        s[0] = p[3] * s[0] + (1.0 - p[3]) * s[1];
    }
    double i_cmp = s[0] / p[0];                                          /* eq. 7 */
    s[2] = w;
    s[3] = 1.0;
    out[0] = s[0];
    out[1] = i_cmp;
    if (!total_prev) {
        double i_tot = i_in + i_cmp;                                     /* eq. 5 */
        s[4] = i_tot;
        s[5] = 1.0;
        out[2] = i_tot;
        out[3] = s[1];
    } else {
        out[2] = s[1];
    }
    return 0;
}
