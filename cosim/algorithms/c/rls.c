/* rls.c: compiled twin of cosim.algorithms.rls.RLSIdentifier, the recursive least
 * squares identification of J, b, fc of thesis Sec. 2.3 (eq. 32-53), both regressions:
 * the thesis' one-step ZOH regression (eq. 44) and the package's integral regression
 * (see rls.py). The same operations in the same order as RLSIdentifier.step (math.fsum
 * is CPython's exact summation, ported below), except numpy's 3x3 products (left to
 * right here): tested to 1e-12 relative (tests/test_rls_kernel.py).
 *
 * The RLS runs offline on a recorded array: cosim_rls_run below is the fast path (one
 * call for the whole record).
 *
 * in: i_cmd [A], w [rad/s], theta_enc [rad] (read by the integral regression only)
 * out: J_hat [kg m^2], b_hat [N m s/rad], fc_hat [N m], theta_a1 [-],
 *      theta_b0 [rad/s per N m], theta_fcb0 [rad/s], e_pred, updated [-]
 */
#include <math.h>
#include "cosim_kernel.h"

typedef struct {                 /* rls.RLSParamsC */
    double Ts_s;                 /* sampling time */
    double Kt_Nm_per_A;          /* torque constant: tau = Kt i */
    double forgetting_factor;    /* lambda of eq. 33, 49, 50 */
    double coulomb_regressor_sign;    /* -1 (friction opposes motion) or +1 (eq. 36 printed) */
    double i_cmd_is_previous;    /* 1: i_cmd was held over the last interval */
    double skip_reversals;       /* 1: skip samples with w_{k-1} w_k <= 0 */
    double w_min_rad_s;          /* skip samples with |w| below this */
    double integral;             /* 1: integral regression, 0: eq. 44 */
    double window_samples;       /* N of the integral regression */
    double interval_mean;        /* 1: w is the mean speed over the last interval */
} rls_params;

typedef struct {                 /* rls.RLSStateC */
    double theta[3];             /* eq. 43 vector (integral: [J, b, fc]) */
    double P[9];                 /* eq. 47/50, row major */
    double e_pred;               /* a-priori error of the last update (eq. 34) */
    double w_prev_rad_s;
    double has_w_prev;
    double tau_prev_Nm;          /* torque issued at the previous tick */
    double has_tau_prev;
    double n_updates;
    double Sxx[9];               /* forgetting-weighted sums of RLSIdentifier.update */
    double Sxx2[9];
    double Sxy[3];
    double Syy;
    double Sw;
    double Sw2;
    double run;                  /* consecutive usable speeds of one sign (integral) */
    double n_w;                  /* entries in the w, theta histories (<= N + 2) */
    double n_sgn;                /* entries in the sign history (<= N + 1) */
    double n_tau;                /* entries in the torque history (<= N + 1) */
    double history[];            /* integral: w[N+2], theta[N+2], tau[N+1], sign[N+1], oldest first */
} rls_state;

/* math.fsum: Shewchuk's exact summation with CPython's final correctly rounded step
 * (finite values; 64 partials are far more than a sum of doubles of one record needs) */
static double fsum(const double *v, long n)
{
    double p[64], x, y, t, hi = 0.0, lo = 0.0, yr;
    int m = 0, i, j;
    long k;
    for (k = 0; k < n; k++) {
        x = v[k];
        for (i = j = 0; j < m; j++) {
            y = p[j];
            if (fabs(x) < fabs(y)) { t = x; x = y; y = t; }
            hi = x + y;
            lo = y - (hi - x);
            if (lo != 0.0)
                p[i++] = lo;
            x = hi;
        }
        m = i;
        if (m < 64)
            p[m++] = x;
    }
    if (m == 0)
        return 0.0;
    hi = p[--m];
    while (m > 0) {
        x = hi;
        y = p[--m];
        hi = x + y;
        yr = hi - x;
        lo = y - yr;
        if (lo != 0.0)
            break;
    }
    if (m > 0 && ((lo < 0.0 && p[m - 1] < 0.0) || (lo > 0.0 && p[m - 1] > 0.0))) {
        y = lo * 2.0;
        x = hi + y;
        yr = x - hi;
        if (y == yr)
            hi = x;
    }
    return hi;
}

static double sgn(double w)      /* np.sign */
{
    if (w != w)
        return w;
    return (double)((w > 0.0) - (w < 0.0));
}

/* deque(maxlen=cap).append: a (oldest first) holds n values; returns the new count */
static long push(double *a, long n, long cap, double v)
{
    if (n < cap) {
        a[n] = v;
        return n + 1;
    }
    for (long j = 1; j < cap; j++)
        a[j - 1] = a[j];
    a[cap - 1] = v;
    return cap;
}

/* RLSIdentifier.update: one RLS step (eq. 34, 48-50) and the weighted sums */
static void update(const rls_params *p, rls_state *s, const double *x, double y)
{
    double lam = p->forgetting_factor, Px[3], g[3], T[9], xPx, e, th;
    int i, j;
    for (i = 0; i < 3; i++)
        Px[i] = s->P[3 * i] * x[0] + s->P[3 * i + 1] * x[1] + s->P[3 * i + 2] * x[2];
    xPx = x[0] * Px[0] + x[1] * Px[1] + x[2] * Px[2];
    for (i = 0; i < 3; i++)
        g[i] = Px[i] / (lam + xPx);                                   /* eq. 49 */
    th = s->theta[0] * x[0] + s->theta[1] * x[1] + s->theta[2] * x[2];
    e = y - th;                                                       /* eq. 34 */
    for (i = 0; i < 3; i++)
        s->theta[i] = s->theta[i] + e * g[i];                         /* eq. 48 */
    for (i = 0; i < 3; i++)
        for (j = 0; j < 3; j++)
            T[3 * i + j] = (s->P[3 * i + j] - g[i] * Px[j]) / lam;    /* eq. 50 */
    for (i = 0; i < 3; i++)
        for (j = 0; j < 3; j++)
            s->P[3 * i + j] = 0.5 * (T[3 * i + j] + T[3 * j + i]);   /* symmetric */
    for (i = 0; i < 3; i++)
        for (j = 0; j < 3; j++) {
            double xx = x[i] * x[j];
            s->Sxx[3 * i + j] = lam * s->Sxx[3 * i + j] + xx;
            s->Sxx2[3 * i + j] = lam * lam * s->Sxx2[3 * i + j] + xx;
        }
    for (i = 0; i < 3; i++)
        s->Sxy[i] = lam * s->Sxy[i] + x[i] * y;
    s->Syy = lam * s->Syy + y * y;
    s->Sw = lam * s->Sw + 1.0;
    s->Sw2 = lam * lam * s->Sw2 + 1.0;
    s->n_updates += 1.0;
    s->e_pred = e;
}

/* theta_to_physical (eq. 51-53) */
static void to_physical(const double *th, double Ts, double *out)
{
    double a1 = th[0], b0 = th[1], fcb0 = th[2], b, fc, J, nl;
    if (b0 == 0.0 || !isfinite(b0)) {
        out[0] = out[1] = out[2] = NAN;
        return;
    }
    b = (1.0 - a1) / b0;                                              /* eq. 51 */
    fc = fcb0 / b0;                                                   /* eq. 52 */
    if (a1 <= 0.0) {
        J = NAN;
    } else {
        nl = -log1p(a1 - 1.0);
        J = nl == 0.0 ? Ts / b0 : Ts * (1.0 - a1) / (b0 * nl);        /* eq. 53 */
    }
    out[0] = J; out[1] = b; out[2] = fc;
}

static int step_eq44(const rls_params *p, rls_state *s, const double *in, double *out)
{
    double w = in[1], tau = p->Kt_Nm_per_A * in[0], x[3], phys[3];
    int prev = p->i_cmd_is_previous != 0.0;
    int has_held = prev || s->has_tau_prev != 0.0;
    double tau_held = prev ? tau : s->tau_prev_Nm;
    double wp = s->w_prev_rad_s;
    int informative = s->has_w_prev != 0.0 && has_held
        && !(p->skip_reversals != 0.0 && wp * w <= 0.0)
        && fabs(wp) >= p->w_min_rad_s && fabs(w) >= p->w_min_rad_s;
    if (informative) {                                                /* eq. 44, 45 */
        x[0] = wp; x[1] = tau_held; x[2] = p->coulomb_regressor_sign * sgn(wp);
        update(p, s, x, w);
    }
    s->w_prev_rad_s = w; s->has_w_prev = 1.0;
    s->tau_prev_Nm = tau; s->has_tau_prev = 1.0;
    to_physical(s->theta, p->Ts_s, phys);
    out[0] = phys[0]; out[1] = phys[1]; out[2] = phys[2];
    out[3] = s->theta[0]; out[4] = s->theta[1]; out[5] = s->theta[2];
    out[6] = s->e_pred; out[7] = informative;
    return 0;
}

static int step_integral(const rls_params *p, rls_state *s, const double *in, double *out)
{
    long N = (long)p->window_samples, nw, nt, ns;
    int mean = p->interval_mean != 0.0;
    double *hw = s->history, *hth = hw + (N + 2), *htau = hth + (N + 2), *hsg = htau + (N + 1);
    double w = in[1], th = in[2], tau = p->Kt_Nm_per_A * in[0], x[3], y = 0.0;
    double Ts = p->Ts_s, sgn_c = -p->coulomb_regressor_sign;
    int prev = p->i_cmd_is_previous != 0.0;
    int has_held = prev || s->has_tau_prev != 0.0;
    double tau_held = prev ? tau : s->tau_prev_Nm;
    /* run of usable speeds: |w| >= w_min and (with skip_reversals) one sign */
    int usable = fabs(w) >= p->w_min_rad_s && w != 0.0;
    int same = s->has_w_prev != 0.0 && s->w_prev_rad_s * w > 0.0;
    if (!usable)
        s->run = 0.0;
    else if (same || p->skip_reversals == 0.0)
        s->run += 1.0;
    else
        s->run = 1.0;
    nw = (long)s->n_w;
    push(hth, nw, N + 2, th);
    nw = push(hw, nw, N + 2, w);
    ns = push(hsg, (long)s->n_sgn, N + 1, sgn(w));   /* the sign over [t_{j-1}, t_j) at t_j */
    nt = has_held ? push(htau, (long)s->n_tau, N + 1, tau_held) : 0;
    s->n_w = (double)nw; s->n_sgn = (double)ns; s->n_tau = (double)nt;
    int informative = s->run >= (double)(N + 1 + mean) && nt >= N + mean && nw >= N + 1 + mean;
    if (informative && !mean) {
        /* w_k: the speed at t_k; the window is [t_{k-N}, t_k] */
        y = Ts * fsum(htau + nt - N, N);                           /* Ts sum tau_j */
        x[0] = w - hw[nw - 1 - N];                                  /* J: w_k - w_{k-N} */
        x[1] = th - hth[nw - 1 - N];                                /* b: theta_k - theta_{k-N} */
        x[2] = sgn_c * Ts * fsum(hsg + ns - N, N);                  /* fc: Ts sum sign(w_j) */
    } else if (informative) {
        /* w_k: the mean speed over [t_{k-1}, t_k]: end intervals at half weight, the
         * angle at its interval mean */
        y = Ts * (fsum(htau + 1, nt - 2) + 0.5 * (htau[0] + htau[nt - 1]));
        x[0] = w - hw[nw - 1 - N];
        x[1] = 0.5 * (hth[nw - 1] + hth[nw - 2]) - 0.5 * (hth[nw - 1 - N] + hth[nw - 2 - N]);
        x[2] = sgn_c * Ts * (fsum(hsg + 1, ns - 2) + 0.5 * (hsg[0] + hsg[ns - 1]));
    }
    if (informative)
        update(p, s, x, y);                                         /* eq. 34, 48-50 */
    s->w_prev_rad_s = w; s->has_w_prev = 1.0;
    s->tau_prev_Nm = tau; s->has_tau_prev = 1.0;
    double J = s->theta[0], b = s->theta[1], fc = s->theta[2];
    int any = s->theta[0] != 0.0 || s->theta[1] != 0.0 || s->theta[2] != 0.0;
    if (!(J > 0.0 && isfinite(J) && isfinite(b)) || !any) {
        out[3] = out[4] = out[5] = NAN;
    } else {                                                        /* eq. 39 */
        double a1 = exp(-Ts * b / J);
        double b0 = b != 0.0 ? (1.0 - a1) / b : Ts / J;
        out[3] = a1; out[4] = b0; out[5] = fc * b0;
    }
    if (s->n_updates >= 3.0) {
        out[0] = J; out[1] = b; out[2] = fc;
    } else {                 /* before: the P0 prior, NaN like eq. 51-53's undefined */
        out[0] = out[1] = out[2] = NAN;
    }
    out[6] = s->e_pred; out[7] = informative;
    return 0;
}

int cosim_kernel_rls(const void *params, void *state, const double *in, double *out)
{
    const rls_params *p = params;
    if (p->integral != 0.0)
        return step_integral(p, state, in, out);
    return step_eq44(p, state, in, out);
}

/* n ticks of the kernel above: in (n x 3: i_cmd, w, theta_enc), out (n x 8). Returns 0,
 * or the first nonzero code of a tick. */
long cosim_rls_run(const void *params, void *state, const double *in, double *out, long n)
{
    long k;
    for (k = 0; k < n; k++) {
        int code = cosim_kernel_rls(params, state, in + 3 * k, out + 8 * k);
        if (code != 0)
            return code;
    }
    return 0;
}
