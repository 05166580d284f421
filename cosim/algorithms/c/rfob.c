/* rfob.c: compiled step of cosim.algorithms.dob.RFOB, the reaction force observer of
 * thesis eq. 10 with the identified ZOH model (eq. 39-40), see dob.py. Same arithmetic
 * in the same order as RFOB.step (bit-identical, tests/test_kernels.py).
 *
 * p: [0] Ts [s]  [1] pole exp(-g Ts)  [2] fc_hat [N m]  [3] w_eps [rad/s]  [4] a1
 *    [5] b0  [6] Kt_hat [N m/A]  [7] tau_l [N m]  [8] lead [m]
 *    [9] 1 = i_cmd is the current held over the last interval
 * s: [0] tau_hat [N m]  [1] tau_raw [N m]  [2] w_k-1  [3] has w_k-1  [4] i_k-1 [A]
 *    [5] has i_k-1
 * in: i_cmd [A], w [rad/s]
 * out: tau_ext_hat [N m], f_ext_hat [N], f_int_hat [N], tau_raw [N m]
 */
#include <math.h>
#include "cosim_kernel.h"

#define PI 3.141592653589793    /* math.pi, the same double */

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

int cosim_kernel_rfob(const double *p, double *s, const double *in, double *out)
{
    double i_in = in[0], w = in[1];
    int prev = p[9] != 0.0;
    int has_held = prev || s[5] != 0.0;
    double i_held = prev ? i_in : s[4];
    if (s[3] != 0.0 && has_held) {
        double w_mid = 0.5 * (w + s[2]);
        double tau_f = p[2] * smooth_sign(w_mid, p[3]);        /* Coulomb part of tau_f */
        /* eq. 10 (external = -reaction), inertia + viscous via the ZOH model eq. 39-40 */
        s[1] = (w - p[4] * s[2]) / p[5] - p[6] * i_held + tau_f + p[7];
        s[0] = p[1] * s[0] + (1.0 - p[1]) * s[1];                        /* g/(s+g) */
    }
    s[2] = w;
    s[3] = 1.0;
    s[4] = i_in;
    s[5] = 1.0;
    double f_ext = s[0] * 2.0 * PI / p[8];                 /* tau = f lead/(2 pi) */
    out[0] = s[0];
    out[1] = f_ext;
    out[2] = -f_ext;
    out[3] = s[1];
    return 0;
}
