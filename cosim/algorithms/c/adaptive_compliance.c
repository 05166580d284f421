/* adaptive_compliance.c: compiled step of the two-axis
 * cosim.algorithms.adaptive_compliance.AdaptiveComplianceController (its _step_2d;
 * thesis Ch. 3, eq. 62-74; adaptive_compliance_xy of the reaching and circular trials).
 *
 * The same operations in the same order as the Python step, except two that numpy
 * does its own way: np.exp (numpy's SIMD exp differs from libm's exp by 1 ulp on about
 * 5 % of arguments) and the dot products g.g and a g (OpenBLAS sums in blocks); here
 * exp is libm's and the sums run left to right. Tested to 1e-12 relative
 * (tests/test_kernels.py), not bit-identical.
 *
 * p: [0] Ts [s]  [1] k [N/(m^2 s)]  [2] tau [s]  [3] clamp of every height [N/m]
 *    (a_min with clamp_weights, the package's extension; -inf: the law as printed)  [4] xi
 *    [5] 1 = physical damping form  [6] m_x [kg]  [7] m_y [kg]  [8] c/((2 pi) sqrt(det S))
 *    [9] -1/(2 sigma_x^2)  [10] -1/(2 sigma_y^2) [1/m^2]  [11] cells per axis m
 *    [12 .. 12+m) centres along x [m], [12+m .. 12+2m) centres along y [m]
 *    [12+2m] snapshot every n ticks (0: none)  [13+2m] room for snapshots
 * s: [0 .. 2P) heights a (axis x: P, then axis y: P; P = m^2, cell (i, j) at i m + j)
 *    [2P] has x~_k-1  [2P+1] x~_x,k-1  [2P+2] x~_y,k-1  [2P+3] motors on
 *    [2P+4] kp_x  [2P+5] kp_y  [2P+6] kd_x  [2P+7] kd_y  [2P+8] ticks stepped
 *    [2P+9] snapshots taken, then that many (tick, a (2P)) records (the trials'
 *    AdaptiveComplianceController.snapshots: the map after each tick that is a multiple of n)
 * Returns 2 when a snapshot is due and there is no room left (state unchanged).
 * in: pos_x, pos_y, ref_x, ref_y [m]
 * out: f_x, f_y [N], kp_x, kp_y [N/m], kd_x, kd_y [N s/m], err_x, err_y [m]
 */
#include <math.h>
#include "cosim_kernel.h"

#define MAXC 64

int cosim_kernel_adaptive_compliance(const double *p, double *s, const double *in,
                                     double *out)
{
    int m = (int)p[11], P = m * m, i, j;
    const double *cx = p + 12, *cy = p + 12 + m;
    double Ts = p[0];
    double x = in[0], y = in[1];
    double ex = in[2] - x;                                    /* x~ = r - x (eq. 65) */
    double ey = in[3] - y;
    double gx[MAXC], gy[MAXC], g[MAXC * MAXC];
    double *ax = s, *ay = s + P, *st = s + 2 * P;
    if (m > MAXC)
        return 1;
    double every = p[12 + 2 * m], tick = st[8];
    int snap = every > 0.0 && fmod(tick, every) == 0.0;
    if (snap && st[9] >= p[13 + 2 * m])
        return 2;                                   /* no room: nothing changed */
    for (i = 0; i < m; i++) {                     /* eq. 63: separable, diagonal S */
        double d = x - cx[i];
        gx[i] = exp(p[9] * d * d);
        d = y - cy[i];
        gy[i] = exp(p[10] * d * d);
    }
    double g2 = 0.0, kpx = 0.0, kpy = 0.0;
    for (i = 0; i < m; i++)
        for (j = 0; j < m; j++) {
            double v = gx[i] * gy[j] * p[8];                /* row of Y(x_k), eq. 62-63 */
            g[i * m + j] = v;
        }
    for (i = 0; i < P; i++) {
        g2 += g[i] * g[i];                                  /* Y Y^T = |g|^2 I */
        kpx += ax[i] * g[i];                                /* Y a_k-1 */
        kpy += ay[i] * g[i];
    }
    /* eq. 71: a_k = a_k-1 + Ts(-1/tau Y^T (YY^T)^-1 Y a_k-1 + k Y^T |x~_k|) */
    double cxo, cyo;
    if (g2 > 1e-300) {
        double inv = 1.0 / (p[2] * g2);
        cxo = Ts * (p[1] * fabs(ex) - kpx * inv);
        cyo = Ts * (p[1] * fabs(ey) - kpy * inv);
    } else {
        cxo = Ts * p[1] * fabs(ex);
        cyo = Ts * p[1] * fabs(ey);
    }
    kpx = kpy = 0.0;
    for (i = 0; i < P; i++) {
        double a = ax[i] + cxo * g[i];
        ax[i] = a < p[3] ? p[3] : a;            /* per-weight clamp (-inf: none, eq. 71) */
        a = ay[i] + cyo * g[i];
        ay[i] = a < p[3] ? p[3] : a;
        kpx += ax[i] * g[i];                                /* eq. 72: k_p = Y(x_k) a_k */
        kpy += ay[i] * g[i];
    }
    /* damping: physical 2 xi sqrt(kp m) or printed xi/2 sqrt(kp) (eq. 60) */
    double kdx, kdy;
    if (p[5] != 0.0) {
        kdx = 2.0 * p[4] * sqrt((0.0 > kpx ? 0.0 : kpx) * p[6]);
        kdy = 2.0 * p[4] * sqrt((0.0 > kpy ? 0.0 : kpy) * p[7]);
    } else {
        kdx = 0.5 * p[4] * sqrt(0.0 > kpx ? 0.0 : kpx);
        kdy = 0.5 * p[4] * sqrt(0.0 > kpy ? 0.0 : kpy);
    }
    double dex = 0.0, dey = 0.0;
    if (st[0] != 0.0) {                                     /* eq. 74, first sample: 0 */
        dex = (ex - st[1]) / Ts;
        dey = (ey - st[2]) / Ts;
    }
    st[0] = 1.0; st[1] = ex; st[2] = ey;
    st[4] = kpx; st[5] = kpy; st[6] = kdx; st[7] = kdy;
    if (snap) {                                     /* (tick, a_k) */
        double *rec = st + 10 + (long)st[9] * (1 + 2 * P);
        rec[0] = tick;
        for (i = 0; i < 2 * P; i++)
            rec[1 + i] = s[i];
        st[9] = st[9] + 1.0;
    }
    st[8] = tick + 1.0;
    if (st[3] != 0.0) {                                     /* eq. 73 */
        out[0] = kpx * ex + kdx * dex;
        out[1] = kpy * ey + kdy * dey;
    } else {                                                /* Table 6: drivers OFF */
        out[0] = out[1] = 0.0;
    }
    out[2] = kpx; out[3] = kpy; out[4] = kdx; out[5] = kdy; out[6] = ex; out[7] = ey;
    return 0;
}
