/* encoder_diff.c: compiled step of cosim.algorithms.aakf.EncoderDifferentiator, the
 * backward-difference estimator of Fig. 24/26 (eq. 30 on the encoder readings). Same
 * arithmetic in the same order as its step (bit-identical, tests/test_kernels.py).
 *
 * in: theta_enc [rad]
 * out: theta_rad, omega_rad_s, alpha_rad_s2, x_m, v_m_s, a_m_s2
 */
#include "cosim_kernel.h"

typedef struct {                 /* aakf.EncoderDiffParamsC */
    double Ts_s;
    double lead_m_per_rad;       /* lead/(2 pi) */
} encoder_diff_params;

typedef struct {                 /* aakf.EncoderDiffStateC */
    double theta_prev_rad;
    double has_theta_prev;
    double omega_prev_rad_s;
    double has_omega_prev;
} encoder_diff_state;

int cosim_kernel_encoder_diff(const void *params, void *state, const double *in, double *out)
{
    const encoder_diff_params *p = params;
    encoder_diff_state *s = state;
    double th = in[0];
    int has_th = s->has_theta_prev != 0.0;
    double omega = has_th ? (th - s->theta_prev_rad) / p->Ts_s : 0.0;     /* eq. 30 */
    double alpha = s->has_omega_prev != 0.0 ? (omega - s->omega_prev_rad_s) / p->Ts_s : 0.0;
    s->omega_prev_rad_s = has_th ? omega : 0.0;
    s->has_omega_prev = has_th ? 1.0 : 0.0;
    s->theta_prev_rad = th;
    s->has_theta_prev = 1.0;
    out[0] = th; out[1] = omega; out[2] = alpha;
    out[3] = p->lead_m_per_rad * th; out[4] = p->lead_m_per_rad * omega;
    out[5] = p->lead_m_per_rad * alpha;
    return 0;
}
