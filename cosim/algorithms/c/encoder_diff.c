/* encoder_diff.c: compiled step of cosim.algorithms.aakf.EncoderDifferentiator, the
 * backward-difference estimator of Fig. 24/26 (eq. 30 on the encoder readings). Same
 * arithmetic in the same order as its step (bit-identical, tests/test_kernels.py).
 *
 * p: [0] Ts [s]  [1] lead/(2 pi) [m/rad]
 * s: [0] theta_k-1 [rad]  [1] has theta_k-1  [2] omega_k-1 [rad/s]  [3] has omega_k-1
 * in: theta_enc [rad]
 * out: theta_rad, omega_rad_s, alpha_rad_s2, x_m, v_m_s, a_m_s2
 */
#include "cosim_kernel.h"

int cosim_kernel_encoder_diff(const double *p, double *s, const double *in, double *out)
{
    double th = in[0];
    int has_th = s[1] != 0.0;
    double omega = has_th ? (th - s[0]) / p[0] : 0.0;                    /* eq. 30 */
    double alpha = s[3] != 0.0 ? (omega - s[2]) / p[0] : 0.0;
    s[2] = has_th ? omega : 0.0;
    s[3] = has_th ? 1.0 : 0.0;
    s[0] = th;
    s[1] = 1.0;
    out[0] = th; out[1] = omega; out[2] = alpha;
    out[3] = p[1] * th; out[4] = p[1] * omega; out[5] = p[1] * alpha;
    return 0;
}
