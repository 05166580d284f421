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
 * Parameters and state are the structs below; the heights come after the state's
 * scalars (axis x: P, then axis y: P; P = m^2, cell (i, j) at i m + j), then the
 * snapshots taken, each a record (tick, a (2P)): the trials'
 * AdaptiveComplianceController.snapshots, the map after each tick that is a multiple
 * of snapshot_every.
 * Returns 2 when a snapshot is due and there is no room left (state unchanged).
 * in: pos_x, pos_y, ref_x, ref_y [m]
 * out: f_x, f_y [N], kp_x, kp_y [N/m], kd_x, kd_y [N s/m], err_x, err_y [m]
 */
#include <math.h>
#include "cosim_kernel.h"

#define MAXC 64

typedef struct {                 /* adaptive_compliance.AdaptiveComplianceParamsC */
    double Ts_s;
    double k_N_per_m2s;          /* adaptation gain k */
    double tau_s;                /* forgetting time constant */
    double a_clamp_N_per_m;      /* clamp of every height (a_min with clamp_weights; -inf: the law as printed) */
    double xi;                   /* damping ratio */
    double physical_damping;     /* 1: 2 xi sqrt(kp m); 0: xi/2 sqrt(kp) as printed */
    double m_x_kg;
    double m_y_kg;
    double prefactor;            /* c/((2 pi) sqrt(det S)) */
    double h_x_per_m2;           /* -1/(2 sigma_x^2) */
    double h_y_per_m2;           /* -1/(2 sigma_y^2) */
    double cells_per_axis;       /* m */
    double snapshot_every;       /* a snapshot every n ticks (0: none) */
    double snapshot_room;        /* snapshots the state has room for */
    double centres_m[];          /* m centres along x, then m along y */
} adaptive_compliance_params;

typedef struct {                 /* adaptive_compliance.AdaptiveComplianceStateC */
    double has_err_prev;
    double err_prev_x_m;         /* x~ of the previous tick */
    double err_prev_y_m;
    double motors_on;
    double kp_x_N_per_m;
    double kp_y_N_per_m;
    double kd_x_Ns_per_m;
    double kd_y_Ns_per_m;
    double ticks;                /* ticks stepped */
    double snapshots;            /* snapshots taken */
    double a_N_per_m[];          /* heights (2P), then the snapshot records */
} adaptive_compliance_state;

int cosim_kernel_adaptive_compliance(const void *params, void *state, const double *in,
                                     double *out)
{
    const adaptive_compliance_params *p = params;
    adaptive_compliance_state *st = state;
    int m = (int)p->cells_per_axis, P = m * m, i, j;
    const double *cx = p->centres_m, *cy = p->centres_m + m;
    double Ts = p->Ts_s;
    double x = in[0], y = in[1];
    double ex = in[2] - x;                                    /* x~ = r - x (eq. 65) */
    double ey = in[3] - y;
    double gx[MAXC], gy[MAXC], g[MAXC * MAXC];
    double *ax = st->a_N_per_m, *ay = st->a_N_per_m + P;
    if (m > MAXC)
        return 1;
    double every = p->snapshot_every, tick = st->ticks;
    int snap = every > 0.0 && fmod(tick, every) == 0.0;
    if (snap && st->snapshots >= p->snapshot_room)
        return 2;                                   /* no room: nothing changed */
    for (i = 0; i < m; i++) {                     /* eq. 63: separable, diagonal S */
        double d = x - cx[i];
        gx[i] = exp(p->h_x_per_m2 * d * d);
        d = y - cy[i];
        gy[i] = exp(p->h_y_per_m2 * d * d);
    }
    double g2 = 0.0, kpx = 0.0, kpy = 0.0;
    for (i = 0; i < m; i++)
        for (j = 0; j < m; j++) {
            double v = gx[i] * gy[j] * p->prefactor;                /* row of Y(x_k), eq. 62-63 */
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
        double inv = 1.0 / (p->tau_s * g2);
        cxo = Ts * (p->k_N_per_m2s * fabs(ex) - kpx * inv);
        cyo = Ts * (p->k_N_per_m2s * fabs(ey) - kpy * inv);
    } else {
        cxo = Ts * p->k_N_per_m2s * fabs(ex);
        cyo = Ts * p->k_N_per_m2s * fabs(ey);
    }
    kpx = kpy = 0.0;
    for (i = 0; i < P; i++) {
        double a = ax[i] + cxo * g[i];
        ax[i] = a < p->a_clamp_N_per_m ? p->a_clamp_N_per_m : a;            /* per-weight clamp (-inf: none, eq. 71) */
        a = ay[i] + cyo * g[i];
        ay[i] = a < p->a_clamp_N_per_m ? p->a_clamp_N_per_m : a;
        kpx += ax[i] * g[i];                                /* eq. 72: k_p = Y(x_k) a_k */
        kpy += ay[i] * g[i];
    }
    /* damping: physical 2 xi sqrt(kp m) or printed xi/2 sqrt(kp) (eq. 60) */
    double kdx, kdy;
    if (p->physical_damping != 0.0) {
        kdx = 2.0 * p->xi * sqrt((0.0 > kpx ? 0.0 : kpx) * p->m_x_kg);
        kdy = 2.0 * p->xi * sqrt((0.0 > kpy ? 0.0 : kpy) * p->m_y_kg);
    } else {
        kdx = 0.5 * p->xi * sqrt(0.0 > kpx ? 0.0 : kpx);
        kdy = 0.5 * p->xi * sqrt(0.0 > kpy ? 0.0 : kpy);
    }
    double dex = 0.0, dey = 0.0;
    if (st->has_err_prev != 0.0) {                                     /* eq. 74, first sample: 0 */
        dex = (ex - st->err_prev_x_m) / Ts;
        dey = (ey - st->err_prev_y_m) / Ts;
    }
    st->has_err_prev = 1.0; st->err_prev_x_m = ex; st->err_prev_y_m = ey;
    st->kp_x_N_per_m = kpx; st->kp_y_N_per_m = kpy;
    st->kd_x_Ns_per_m = kdx; st->kd_y_Ns_per_m = kdy;
    if (snap) {                                     /* (tick, a_k) */
        double *rec = st->a_N_per_m + 2 * P + (long)st->snapshots * (1 + 2 * P);
        rec[0] = tick;
        for (i = 0; i < 2 * P; i++)
            rec[1 + i] = st->a_N_per_m[i];
        st->snapshots = st->snapshots + 1.0;
    }
    st->ticks = tick + 1.0;
    if (st->motors_on != 0.0) {                                     /* eq. 73 */
        out[0] = kpx * ex + kdx * dex;
        out[1] = kpy * ey + kdy * dey;
    } else {                                                /* Table 6: drivers OFF */
        out[0] = out[1] = 0.0;
    }
    out[2] = kpx; out[3] = kpy; out[4] = kdx; out[5] = kdy; out[6] = ex; out[7] = ey;
    return 0;
}
