/* stability_1dof.c: compiled twin of cosim.algorithms.stability.simulate_1dof, the direct
 * simulation of the 1-DOF closed loop of eq. 80 (thesis Sec. 3.3.2.1):
 *
 *     (m_r + M_h) x'' = f_c + K_h (r - x) + b_h (r' - x')        (eq. 75, 79, 80)
 *
 * with f_c the one-axis adaptive compliance step (AdaptiveComplianceController.
 * step_reference for N = 1: eq. 62-74) computed at each tick and held (ZOH) over
 * ``substeps`` RK4 steps of the plant. One tick = one controller sample.
 *
 * The same operations in the same order as the Python reference, except np.exp
 * (numpy's SIMD exp differs from libm's by 1 ulp on some arguments) and the dot
 * products (left to right here): tested to 1e-9 relative (tests/test_kernels.py).
 *
 * p: [0] Ts [s]  [1] k [N/(m^2 s)]  [2] tau [s]  [3] per-weight clamp [N/m] (-inf: none,
 *    the law as printed)  [4] xi  [5] 1 = physical damping form  [6] damping mass [kg]
 *    [7] Gaussian prefactor c/(sqrt(2 pi) sigma)  [8] 1/sigma^2 [1/m^2]
 *    [9] m_r + M_h [kg]  [10] K_h [N/m]  [11] b_h [N s/m]  [12] substeps
 *    [13] cells P (<= 64)  [14 .. 14+P) centres [m]
 * s: [0 .. P) heights a [N/m]  [P] has x~_k-1  [P+1] x~_k-1 [m]  [P+2] motors on
 *    [P+3] x [m]  [P+4] x' [m/s]
 * in: r(t_k), then per substep j (t_j = t_k + j h, h = Ts/substeps): r, r' at t_j,
 *    t_j + h/2, t_j + h (1 + 6 substeps values)
 * out: x [m] (before the plant step), r [m], x~ [m], k_p [N/m], f_c [N]
 */
#include <math.h>
#include "cosim_kernel.h"

#define MAXP 64

static double acc(const double *p, double r, double rd, double x, double v, double f)
{
    return (f + p[10] * (r - x) + p[11] * (rd - v)) / p[9];
}

int cosim_kernel_stability_1dof(const double *p, double *s, const double *in, double *out)
{
    int P = (int)p[13], i, j, nsub = (int)p[12];
    const double *mu = p + 14;
    double Ts = p[0], g[MAXP];
    double *a = s, *st = s + P;
    if (P > MAXP)
        return 1;
    double x = st[3], v = st[4];
    double r = in[0];
    double err = r - x;                                   /* x~ = r - x (eq. 65) */
    double g2 = 0.0, kp_prev = 0.0;
    for (i = 0; i < P; i++) {                             /* row of Y(x_k), eq. 62-63 */
        double d = x - mu[i];
        g[i] = p[7] * exp(-0.5 * (d * d * p[8]));
    }
    for (i = 0; i < P; i++)
        g2 += g[i] * g[i];                                /* Y Y^T = |g|^2 */
    for (i = 0; i < P; i++)
        kp_prev += a[i] * g[i];                           /* Y a_k-1 */
    /* eq. 71: a_k = a_k-1 + Ts(-1/tau Y^T (YY^T)^-1 Y a_k-1 + k Y^T |x~_k|) */
    double kp = 0.0;
    for (i = 0; i < P; i++) {
        double forget = g2 > 1e-300 ? kp_prev / g2 * g[i] / p[2] : 0.0;
        double ai = a[i] + Ts * (-forget + p[1] * (fabs(err) * g[i]));
        a[i] = ai < p[3] ? p[3] : ai;                     /* per-weight clamp (-inf: none) */
    }
    for (i = 0; i < P; i++)
        kp += a[i] * g[i];                                /* eq. 72 */
    double kpc = kp > 0.0 ? kp : 0.0, kd;
    if (p[5] != 0.0)                                      /* damping, eq. 57 / eq. 60 */
        kd = 2.0 * p[4] * sqrt(kpc * p[6]);
    else
        kd = 0.5 * p[4] * sqrt(kpc);
    double derr = st[0] != 0.0 ? (err - st[1]) / Ts : 0.0;   /* eq. 74, first sample: 0 */
    st[0] = 1.0; st[1] = err;
    double f = st[2] != 0.0 ? kp * err + kd * derr : 0.0;   /* eq. 73 */
    out[0] = x; out[1] = r; out[2] = err; out[3] = kp; out[4] = f;
    if (!isfinite(x))
        return 0;
    double h = Ts / nsub;
    for (j = 0; j < nsub; j++) {                          /* RK4 on the plant, f held (ZOH) */
        const double *q = in + 1 + 6 * j;
        double k1x = v, k1v = acc(p, q[0], q[1], x, v, f);
        double k2x = v + 0.5 * h * k1v, k2v = acc(p, q[2], q[3], x + 0.5 * h * k1x, v + 0.5 * h * k1v, f);
        double k3x = v + 0.5 * h * k2v, k3v = acc(p, q[2], q[3], x + 0.5 * h * k2x, v + 0.5 * h * k2v, f);
        double k4x = v + h * k3v, k4v = acc(p, q[4], q[5], x + h * k3x, v + h * k3v, f);
        x += h / 6.0 * (k1x + 2 * k2x + 2 * k3x + k4x);
        v += h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v);
    }
    st[3] = x; st[4] = v;
    return 0;
}

/* n ticks of the kernel above: in (n x (1 + 6 substeps)), out (n x 5). Stops after the
 * tick whose x is not finite or whose |x~| exceeds blowup_m (that row is written, as in
 * the Python loop); returns the number of rows written. */
long cosim_stability_1dof_run(const double *p, double *s, const double *in, double *out,
                              long n, double blowup_m)
{
    long k, nin = 1 + 6 * (long)p[12];
    for (k = 0; k < n; k++) {
        double *o = out + 5 * k;
        if (cosim_kernel_stability_1dof(p, s, in + nin * k, o) != 0)
            return -1;
        if (!isfinite(o[0]) || fabs(o[2]) > blowup_m)
            return k + 1;
    }
    return n;
}
