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
 * Parameters (packed by AaKF.c_kernel / AaKFBank.c_kernel): aakf_params, then (bank)
 *   log sigma_a_i of the n members, then n aakf_member_params, then the gain tables:
 *   rows of (K00, K01, K10, K11, K20, K21, K30, K31, Si00, Si01, Si11, log det S); row
 *   min(k, gain_rows - 1) is the gain of step k once converged.
 * Returns 1 when a step lies past a gain table that has not converged (c_kernel was
 *   asked for fewer ticks than the run takes).
 * State: n aakf_state (one per member), then (bank) aakf_bank_state.
 * in: theta_enc [rad], acc_meas [m/s^2].
 * out: theta_rad, omega_rad_s, alpha_rad_s2, x_m, v_m_s, a_m_s2, bias_m_s2,
 *   innov_enc_rad, innov_acc_m_s2, reset_fired, reset_pos_fired, reset_speed_fired,
 *   then reset_lo, reset_hi (single) or sigma_a_eff (bank).
 */
#include <math.h>
#include "cosim_kernel.h"

typedef struct {                 /* fast.aakf_fast.AakfParamsC */
    double n_members;            /* 1 for a single filter */
    double bank;                 /* 1: the sigma_a bank */
    double Ts_s;
    double Delta_rad;            /* encoder quantum */
    double half_Delta_rad;
    double lead_m_per_rad;       /* lead/(2 pi) */
    double floor_quantiser;      /* 1: floor quantiser (eq. 29 interval [enc, enc + Delta)) */
    double reset_prediction;     /* Sec. 2.2.2 reset of each member on its prediction */
    double reset_posterior;      /* ... on its posterior */
    double member_reset_output;  /* ... on its output */
    double bank_reset_output;    /* ... on the bank's estimate */
    double init_from_first_measurement;
    double eq31_accel;           /* eq. 31 speed bound with the acceleration term */
    double lambda_forgetting;    /* the bank's forgetting lambda */
    double compensated_sum;      /* 1: Python's sum() of floats is Neumaier's (CPython >= 3.12) */
    double tail[];               /* (bank) log sigma_a_i, members, gain tables */
} aakf_params;

typedef struct {                 /* fast.aakf_fast.AakfMemberParamsC */
    double Ad_sparse;            /* 1: A_d has the sparsity of the thesis model */
    double Ad[16];               /* A_d, row-major (eq. 98) */
    double C_acc_alpha;          /* C[1,2]: the accelerometer's row */
    double C_acc_bias;           /* C[1,3] */
    double gain_rows;            /* rows of this member's gain table */
    double gain_offset;          /* where the table starts, in doubles from the parameters' start */
    double gain_converged;       /* 1: the last row is held */
} aakf_member_params;

typedef struct {                 /* fast.aakf_fast.AakfStateC */
    double k;                    /* steps taken */
    double x_post[4];            /* x_k|k */
    double x_pred[4];            /* x_k|k-1 */
    double innov[2];             /* e_k: encoder [rad], accelerometer [m/s^2] */
    double loglik;
    double reset_lo_rad;         /* eq. 29 interval */
    double reset_hi_rad;
    double enc_prev_rad;
    double has_enc_prev;
    double reset_pos;            /* the member's reset flags of this tick (bank) */
    double reset_speed;
} aakf_state;

typedef struct {                 /* fast.aakf_fast.AakfBankStateC */
    double k;
    double has_enc_prev;
    double enc_prev_rad;
    double best;                 /* most probable member */
    double sigma_a_eff;
    double innov[2];
    double x_mix[4];             /* the bank's estimate */
    double weights[];            /* L (n), w (n), w_prior (n) */
} aakf_bank_state;

typedef struct {
    double th, om, al, bi, e0, e1;
    int pos, spd;
} member_out;

/* Python's max(a, b) / min(a, b) for floats: the first argument unless the second is
 * strictly larger / smaller (also the NaN behaviour of the reference) */
static double py_max(double a, double b) { return b > a ? b : a; }
static double py_min(double a, double b) { return b < a ? b : a; }

/* Sec. 2.2.2 on a position [rad] and speed [rad/s] (aakf._clamp) */
static void clamp(const aakf_params *p, double *theta, double *omega, double alpha, double enc,
                  int has_prev, double enc_prev, int *pos, int *spd)
{
    double lo, hi;
    if (p->floor_quantiser != 0.0) { lo = enc; hi = enc + p->Delta_rad; }    /* eq. 29, floor */
    else { lo = enc - 0.5 * p->Delta_rad; hi = enc + 0.5 * p->Delta_rad; }   /* eq. 29 */
    *pos = *theta > hi || *theta < lo;
    *theta = py_min(py_max(*theta, lo), hi);
    *spd = 0;
    if (has_prev) {
        double v = (enc - enc_prev) / p->Ts_s;                           /* eq. 30 */
        if (p->eq31_accel != 0.0)
            v += 0.5 * p->Ts_s * alpha;                  /* eq31_accel: endpoint vs mean speed */
        double dv = p->Delta_rad / p->Ts_s;
        *spd = *omega > v + dv || *omega < v - dv;                       /* eq. 31 */
        *omega = py_min(py_max(*omega, v - dv), v + dv);
    }
}

/* one single filter (AaKF.step): member parameters m, state s */
static int member_step(const aakf_params *p, const aakf_member_params *m, aakf_state *s,
                       double enc, double acc, member_out *o)
{
    const double *A = m->Ad;
    double y_enc = p->floor_quantiser != 0.0 ? enc + p->half_Delta_rad : enc;
    double k = s->k;
    double nK = m->gain_rows;
    if (k >= nK && m->gain_converged == 0.0)
        return 1;                            /* past the packed, unconverged sequence */
    const double *K = (const double *)p + (long)m->gain_offset + 12 * (long)(k < nK ? k : nK - 1.0);
    double x0, x1, x2, x3;
    int pos = 0, spd = 0;
    int has_prev = s->has_enc_prev != 0.0;
    double enc_prev = s->enc_prev_rad;

    if (k == 0.0) {                                        /* x_0 (Appendix A) */
        x0 = p->init_from_first_measurement != 0.0 ? y_enc : 0.0;
        x1 = x2 = x3 = 0.0;
    } else {                                               /* eq. 98 (u = 0) */
        double u0 = s->x_post[0], u1 = s->x_post[1], u2 = s->x_post[2], u3 = s->x_post[3];
        if (m->Ad_sparse != 0.0) {
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
    if (p->floor_quantiser != 0.0) {                                     /* eq. 29 interval */
        s->reset_lo_rad = enc; s->reset_hi_rad = enc + p->Delta_rad;
    } else {
        s->reset_lo_rad = enc - p->half_Delta_rad; s->reset_hi_rad = enc + p->half_Delta_rad;
    }
    if (p->reset_prediction != 0.0)                                       /* Sec. 2.2.2 on the prediction */
        clamp(p, &x0, &x1, x2, enc, has_prev, enc_prev, &pos, &spd);

    double e0 = y_enc - x0;                                                /* eq. 101 */
    double e1 = acc - (m->C_acc_alpha * x2 + m->C_acc_bias * x3);
    /* Gaussian log-likelihood of the innovation (the bank's weights) */
    s->loglik = -0.5 * (K[11] + (K[8] * e0 * e0 + 2.0 * K[9] * e0 * e1 + K[10] * e1 * e1));
    s->x_pred[0] = x0; s->x_pred[1] = x1; s->x_pred[2] = x2; s->x_pred[3] = x3;
    x0 = x0 + (K[0] * e0 + K[1] * e1);                                     /* eq. 102 */
    x1 = x1 + (K[2] * e0 + K[3] * e1);
    x2 = x2 + (K[4] * e0 + K[5] * e1);
    x3 = x3 + (K[6] * e0 + K[7] * e1);
    if (p->reset_posterior != 0.0)                         /* variant: on the posterior */
        clamp(p, &x0, &x1, x2, enc, has_prev, enc_prev, &pos, &spd);
    s->x_post[0] = x0; s->x_post[1] = x1; s->x_post[2] = x2; s->x_post[3] = x3;
    s->innov[0] = e0; s->innov[1] = e1;
    s->enc_prev_rad = enc; s->has_enc_prev = 1.0;
    s->k = k + 1.0;
    if (p->member_reset_output != 0.0)                                       /* variant: the output only */
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

int cosim_kernel_aakf(const void *params, void *state, const double *in, double *out)
{
    const aakf_params *p = params;
    aakf_state *s = state;
    int n = (int)p->n_members;
    double enc = in[0], acc = in[1];
    const double *log_sa = p->tail;
    const aakf_member_params *mp =
        (const aakf_member_params *)(p->tail + (p->bank != 0.0 ? n : 0));
    member_out o;

    if (p->bank == 0.0) {                                  /* one filter (AaKF) */
        if (member_step(p, mp, s, enc, acc, &o))
            return 1;
        outputs(p->lead_m_per_rad, o.th, o.om, o.al, o.bi, o.e0, o.e1, o.pos, o.spd, out);
        out[12] = s->reset_lo_rad;
        out[13] = s->reset_hi_rad;
        return 0;
    }

    /* the sigma_a bank (AaKFBank.step): every member steps, then the weights */
    aakf_bank_state *b = (aakf_bank_state *)(s + n);
    double *L = b->weights, *w = L + n, *wp = w + n;
    double lam = p->lambda_forgetting;
    double th = 0.0, om = 0.0, al = 0.0, bi = 0.0, e0 = 0.0, e1 = 0.0;
    double top = 0.0, tot, eff;
    int best = 0, pos, spd;
    int i;
    for (i = 0; i < n; i++)                   /* nothing changes when a table ends */
        if (s[i].k >= mp[i].gain_rows && mp[i].gain_converged == 0.0)
            return 1;
    for (i = 0; i < n; i++)
        wp[i] = w[i];                         /* w_k-1: the prior weights of this tick */
    for (i = 0; i < n; i++) {
        aakf_state *si = s + i;
        (void)member_step(p, mp + i, si, enc, acc, &o);
        si->reset_pos = (double)o.pos;        /* the member's reset flags of this tick */
        si->reset_speed = (double)o.spd;
        L[i] = lam * L[i] + si->loglik;           /* L_i,k = lambda L_i,k-1 + l_i,k */
        if (i == 0 || L[i] > top)             /* max(L): the first of equal maxima */
            top = L[i];
    }
    for (i = 0; i < n; i++) {
        L[i] = L[i] - top;                    /* keep exp() in range; w unchanged */
        w[i] = exp(L[i]);
    }
    tot = py_sum(w, (const double *)0, n, p->compensated_sum != 0.0);   /* sum(ex) */
    for (i = 0; i < n; i++) {
        w[i] = w[i] / tot;                    /* w_i,k = exp(L_i,k) / sum_j exp(L_j,k) */
        if (w[i] > w[best])                   /* most probable member (first of equals) */
            best = i;
    }
    eff = py_sum(w, log_sa, n, p->compensated_sum != 0.0);  /* sum(w_i log sigma_a_i) */
    b->sigma_a_eff = exp(eff);                          /* sigma_a_eff = exp(sum_i w_i log sigma_a_i) */
    /* the bank's estimate sum_i w_i,k x_i,k|k (members have no output-stage reset,
     * so x_i,k|k is member i's output) and innovation sum_i w_i,k-1 e_i,k */
    for (i = 0; i < n; i++) {
        const aakf_state *si = s + i;
        th += w[i] * si->x_post[0];
        om += w[i] * si->x_post[1];
        al += w[i] * si->x_post[2];
        bi += w[i] * si->x_post[3];
        e0 += wp[i] * si->innov[0];
        e1 += wp[i] * si->innov[1];
    }
    b->innov[0] = e0; b->innov[1] = e1;
    b->x_mix[0] = th; b->x_mix[1] = om; b->x_mix[2] = al; b->x_mix[3] = bi;
    b->k = b->k + 1.0;
    b->best = (double)best;
    pos = s[best].reset_pos != 0.0;
    spd = s[best].reset_speed != 0.0;
    if (p->bank_reset_output != 0.0)                         /* Sec. 2.2.2 on the bank's estimate */
        clamp(p, &th, &om, al, enc, b->has_enc_prev != 0.0, b->enc_prev_rad, &pos, &spd);
    b->has_enc_prev = 1.0;
    b->enc_prev_rad = enc;
    outputs(p->lead_m_per_rad, th, om, al, bi, e0, e1, pos, spd, out);
    out[12] = b->sigma_a_eff;
    return 0;
}
