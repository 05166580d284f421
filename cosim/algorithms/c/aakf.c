/* aakf.c: compiled step of cosim.algorithms.fast.aakf_fast.AaKF (one filter) and AaKFBank
 * (the sigma_a bank), thesis Sec. 2.2 / Appendix A with the state reset of Sec. 2.2.2.
 *
 * The readable reference is cosim.algorithms.aakf.ReferenceAaKF (eq. 98-103 one per
 * line); its fast Python form AaKF is tested equal to it (tests/test_aakf_fast.py) and
 * this file is the same arithmetic as AaKF in the same order (bit-identical,
 * tests/test_kernels.py). The gain K_k (eq. 99, 100, 103) does not
 * depend on the data: AaKF.c_kernel(ticks) packs the shared precomputed sequence (for
 * the ticks of the run, or to convergence, then held) into p, with the inverse and
 * log-determinant of S_k = C P_k|k-1 C^T + R (eq. 100) that the bank's likelihood needs.
 *
 * p (packed by AaKF.c_kernel / AaKFBank.c_kernel):
 *   [0] n members (1 for a single filter)   [1] 1 = bank
 *   [2] Ts [s]  [3] Delta [rad]  [4] Delta/2 [rad]  [5] lead/(2 pi) [m/rad]
 *   [6] floor quantiser  [7] member reset on the prediction  [8] on the posterior
 *   [9] member reset on the output  [10] bank reset on the output (bank's estimate)
 *   [11] init from first measurement  [12] eq31_accel  [13] lambda (bank forgetting)
 *   [14] 1 = Python's sum() of floats is compensated (Neumaier; CPython >= 3.12)
 *   [15 .. 15+n) log sigma_a_i (bank only)
 *   then per member MB doubles: Ad sparse flag, Ad (16, row-major), C[1,2], C[1,3],
 *   number of gain entries nK, offset of the gain table in p, 1 = the sequence has
 *   converged (its last entry is held);
 *   gain table: nK rows of (K00, K01, K10, K11, K20, K21, K30, K31, Si00, Si01, Si11,
 *   log det S); row min(k, nK - 1) is the gain of step k once converged.
 * Returns 1 when a step lies past a gain table that has not converged (c_kernel was
 * asked for fewer ticks than the run takes).
 * s: per member MS doubles: k, x_k|k (4), x_k|k-1 (4), e_k (2), loglik, reset_lo,
 *   reset_hi, theta_enc_k-1, has theta_enc_k-1, reset_pos, reset_speed (bank);
 *   then (bank) k, has enc_prev, enc_prev, best member, sigma_a_eff, e (2),
 *   x mix (4), L (n), w (n), w_prior (n).
 * in: theta_enc [rad], acc_meas [m/s^2].
 * out: theta_rad, omega_rad_s, alpha_rad_s2, x_m, v_m_s, a_m_s2, bias_m_s2,
 *   innov_enc_rad, innov_acc_m_s2, reset_fired, reset_pos_fired, reset_speed_fired,
 *   then reset_lo, reset_hi (single) or sigma_a_eff (bank).
 */
#include <math.h>
#include "cosim_kernel.h"

#define HDR 15
#define MB 22
#define MS 18

typedef struct {
    double th, om, al, bi, e0, e1;
    int pos, spd;
} member_out;

/* Python's max(a, b) / min(a, b) for floats: the first argument unless the second is
 * strictly larger / smaller (also the NaN behaviour of the reference) */
static double py_max(double a, double b) { return b > a ? b : a; }
static double py_min(double a, double b) { return b < a ? b : a; }

/* Sec. 2.2.2 on a position [rad] and speed [rad/s] (aakf._clamp) */
static void clamp(const double *p, double *theta, double *omega, double alpha, double enc,
                  int has_prev, double enc_prev, int *pos, int *spd)
{
    double lo, hi;
    if (p[6] != 0.0) { lo = enc; hi = enc + p[3]; }                     /* eq. 29, floor */
    else { lo = enc - 0.5 * p[3]; hi = enc + 0.5 * p[3]; }               /* eq. 29 */
    *pos = *theta > hi || *theta < lo;
    *theta = py_min(py_max(*theta, lo), hi);
    *spd = 0;
    if (has_prev) {
        double v = (enc - enc_prev) / p[2];                              /* eq. 30 */
        if (p[12] != 0.0)
            v += 0.5 * p[2] * alpha;                  /* eq31_accel: endpoint vs mean speed */
        double dv = p[3] / p[2];
        *spd = *omega > v + dv || *omega < v - dv;                       /* eq. 31 */
        *omega = py_min(py_max(*omega, v - dv), v + dv);
    }
}

/* one single filter (AaKF.step): member parameters m, state s */
static int member_step(const double *p, const double *m, double *s, double enc, double acc,
                       member_out *o)
{
    const double *A = m + 1;
    double y_enc = p[6] != 0.0 ? enc + p[4] : enc;
    double k = s[0];
    double nK = m[19];
    if (k >= nK && m[21] == 0.0)
        return 1;                            /* past the packed, unconverged sequence */
    const double *K = p + (long)m[20] + 12 * (long)(k < nK ? k : nK - 1.0);
    double x0, x1, x2, x3;
    int pos = 0, spd = 0;
    int has_prev = s[15] != 0.0;
    double enc_prev = s[14];

    if (k == 0.0) {                                        /* x_0 (Appendix A) */
        x0 = p[11] != 0.0 ? y_enc : 0.0;
        x1 = x2 = x3 = 0.0;
    } else {                                               /* eq. 98 (u = 0) */
        double u0 = s[1], u1 = s[2], u2 = s[3], u3 = s[4];
        if (m[0] != 0.0) {
            x0 = (A[0] * u0 + A[2] * u2) + A[1] * u1;
            x1 = A[5] * u1 + A[6] * u2;
            x2 = A[10] * u2;
            x3 = A[15] * u3;
        } else {
            x0 = A[0] * u0 + A[1] * u1 + A[2] * u2 + A[3] * u3;
            x1 = A[4] * u0 + A[5] * u1 + A[6] * u2 + A[7] * u3;
            x2 = A[8] * u0 + A[9] * u1 + A[10] * u2 + A[11] * u3;
            x3 = A[12] * u0 + A[13] * u1 + A[14] * u2 + A[15] * u3;
        }
    }
    if (p[6] != 0.0) { s[12] = enc; s[13] = enc + p[3]; }               /* eq. 29 interval */
    else { s[12] = enc - p[4]; s[13] = enc + p[4]; }
    if (p[7] != 0.0)                                       /* Sec. 2.2.2 on the prediction */
        clamp(p, &x0, &x1, x2, enc, has_prev, enc_prev, &pos, &spd);

    double e0 = y_enc - x0;                                                /* eq. 101 */
    double e1 = acc - (m[17] * x2 + m[18] * x3);
    /* Gaussian log-likelihood of the innovation (the bank's weights) */
    s[11] = -0.5 * (K[11] + (K[8] * e0 * e0 + 2.0 * K[9] * e0 * e1 + K[10] * e1 * e1));
    s[5] = x0; s[6] = x1; s[7] = x2; s[8] = x3;
    x0 = x0 + (K[0] * e0 + K[1] * e1);                                     /* eq. 102 */
    x1 = x1 + (K[2] * e0 + K[3] * e1);
    x2 = x2 + (K[4] * e0 + K[5] * e1);
    x3 = x3 + (K[6] * e0 + K[7] * e1);
    if (p[8] != 0.0)                                       /* variant: on the posterior */
        clamp(p, &x0, &x1, x2, enc, has_prev, enc_prev, &pos, &spd);
    s[1] = x0; s[2] = x1; s[3] = x2; s[4] = x3;
    s[9] = e0; s[10] = e1;
    s[14] = enc; s[15] = 1.0;
    s[0] = k + 1.0;
    if (p[9] != 0.0)                                       /* variant: the output only */
        clamp(p, &x0, &x1, x2, enc, has_prev, enc_prev, &pos, &spd);
    o->th = x0; o->om = x1; o->al = x2; o->bi = x3; o->e0 = e0; o->e1 = e1;
    o->pos = pos; o->spd = spd;
    return 0;
}

/* Python's sum() of the n >= 1 floats x_i = a[i] (b NULL) or a[i] * b[i], start 0:
 * 0 + x_0, then plain additions (CPython <= 3.11) or Neumaier's compensated summation
 * (CPython >= 3.12, Python/bltinmodule.c) */
static double py_sum(const double *a, const double *b, int n, int compensated)
{
    double f = 0.0 + (b ? a[0] * b[0] : a[0]), c = 0.0;
    for (int i = 1; i < n; i++) {
        double x = b ? a[i] * b[i] : a[i];
        if (compensated) {
            double t = f + x;
            if (fabs(f) >= fabs(x))
                c += (f - t) + x;
            else
                c += (x - t) + f;
            f = t;
        } else {
            f += x;
        }
    }
    if (compensated && c != 0.0 && isfinite(c))
        f += c;
    return f;
}

static void outputs(double sc, double th, double om, double al, double bi, double e0,
                    double e1, int pos, int spd, double *out)
{
    out[0] = th; out[1] = om; out[2] = al;
    out[3] = sc * th; out[4] = sc * om; out[5] = sc * al;
    out[6] = bi; out[7] = e0; out[8] = e1;
    out[9] = (pos || spd) ? 1.0 : 0.0;
    out[10] = pos ? 1.0 : 0.0;
    out[11] = spd ? 1.0 : 0.0;
}

int cosim_kernel_aakf(const double *p, double *s, const double *in, double *out)
{
    int n = (int)p[0];
    double enc = in[0], acc = in[1];
    const double *log_sa = p + HDR;
    const double *mp = p + HDR + (p[1] != 0.0 ? n : 0);
    member_out o;

    if (p[1] == 0.0) {                                     /* one filter (AaKF) */
        if (member_step(p, mp, s, enc, acc, &o))
            return 1;
        outputs(p[5], o.th, o.om, o.al, o.bi, o.e0, o.e1, o.pos, o.spd, out);
        out[12] = s[12];
        out[13] = s[13];
        return 0;
    }

    /* the sigma_a bank (AaKFBank.step): every member steps, then the weights */
    double *b = s + MS * n;
    double *L = b + 11, *w = L + n, *wp = w + n;
    double lam = p[13];
    double th = 0.0, om = 0.0, al = 0.0, bi = 0.0, e0 = 0.0, e1 = 0.0;
    double top = 0.0, tot, eff;
    int best = 0, pos, spd;
    int i;
    for (i = 0; i < n; i++)                   /* nothing changes when a table ends */
        if (s[MS * i] >= mp[MB * i + 19] && mp[MB * i + 21] == 0.0)
            return 1;
    for (i = 0; i < n; i++)
        wp[i] = w[i];                         /* w_k-1: the prior weights of this tick */
    for (i = 0; i < n; i++) {
        double *si = s + MS * i;
        (void)member_step(p, mp + MB * i, si, enc, acc, &o);
        si[16] = (double)o.pos;               /* the member's reset flags of this tick */
        si[17] = (double)o.spd;
        L[i] = lam * L[i] + si[11];           /* L_i,k = lambda L_i,k-1 + l_i,k */
        if (i == 0 || L[i] > top)             /* max(L): the first of equal maxima */
            top = L[i];
    }
    for (i = 0; i < n; i++) {
        L[i] = L[i] - top;                    /* keep exp() in range; w unchanged */
        w[i] = exp(L[i]);
    }
    tot = py_sum(w, (const double *)0, n, p[14] != 0.0);   /* sum(ex) */
    for (i = 0; i < n; i++) {
        w[i] = w[i] / tot;                    /* w_i,k = exp(L_i,k) / sum_j exp(L_j,k) */
        if (w[i] > w[best])                   /* most probable member (first of equals) */
            best = i;
    }
    eff = py_sum(w, log_sa, n, p[14] != 0.0);  /* sum(w_i log sigma_a_i) */
    b[4] = exp(eff);                          /* sigma_a_eff = exp(sum_i w_i log sigma_a_i) */
    /* the bank's estimate sum_i w_i,k x_i,k|k (members have no output-stage reset,
     * so x_i,k|k is member i's output) and innovation sum_i w_i,k-1 e_i,k */
    for (i = 0; i < n; i++) {
        const double *si = s + MS * i;
        th += w[i] * si[1];
        om += w[i] * si[2];
        al += w[i] * si[3];
        bi += w[i] * si[4];
        e0 += wp[i] * si[9];
        e1 += wp[i] * si[10];
    }
    b[5] = e0; b[6] = e1;
    b[7] = th; b[8] = om; b[9] = al; b[10] = bi;
    b[0] = b[0] + 1.0;
    b[3] = (double)best;
    pos = s[MS * best + 16] != 0.0;
    spd = s[MS * best + 17] != 0.0;
    if (p[10] != 0.0)                         /* Sec. 2.2.2 on the bank's estimate */
        clamp(p, &th, &om, al, enc, b[1] != 0.0, b[2], &pos, &spd);
    b[1] = 1.0;
    b[2] = enc;
    outputs(p[5], th, om, al, bi, e0, e1, pos, spd, out);
    out[12] = b[4];
    return 0;
}
