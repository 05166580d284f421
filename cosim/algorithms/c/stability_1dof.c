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
 * Parameters and state: the structs below (the heights after the state's scalars).
 * in: r(t_k), then per substep j (t_j = t_k + j h, h = Ts/substeps): r, r' at t_j,
 *    t_j + h/2, t_j + h (1 + 6 substeps values)
 * out: x [m] (before the plant step), r [m], x~ [m], k_p [N/m], f_c [N]
 */
#include <math.h>
#include "cosim_kernel.h"

#define MAXP 64

typedef struct {                 /* stability.Stability1DofParamsC */
    double Ts_s;
    double k_N_per_m2s;          /* adaptation gain k */
    double tau_s;                /* forgetting time constant */
    double a_clamp_N_per_m;      /* per-weight clamp (-inf: none, the law as printed) */
    double xi;                   /* damping ratio */
    double physical_damping;     /* 1: 2 xi sqrt(kp m); 0: xi/2 sqrt(kp) */
    double damping_mass_kg;
    double prefactor;            /* Gaussian prefactor c/(sqrt(2 pi) sigma) */
    double inv_var_per_m2;       /* 1/sigma^2 */
    double mass_kg;              /* m_r + M_h */
    double K_h_N_per_m;          /* human stiffness */
    double b_h_Ns_per_m;         /* human damping */
    double substeps;             /* RK4 steps per tick */
    double cells;                /* P (<= 64) */
    double centres_m[];          /* P cell centres */
} stability_1dof_params;

typedef struct {                 /* stability.Stability1DofStateC */
    double has_err_prev;
    double err_prev_m;           /* x~ of the previous tick */
    double motors_on;
    double x_m;                  /* plant position */
    double v_m_per_s;            /* plant speed */
    double a_N_per_m[];          /* P heights */
} stability_1dof_state;

static double acc(const stability_1dof_params *p, double r, double rd, double x, double v,
                  double f)
{
    return (f + p->K_h_N_per_m * (r - x) + p->b_h_Ns_per_m * (rd - v)) / p->mass_kg;
}

int cosim_kernel_stability_1dof(const void *params, void *state, const double *in, double *out)
{
    const stability_1dof_params *p = params;
    stability_1dof_state *st = state;
    int P = (int)p->cells, i, j, nsub = (int)p->substeps;
    const double *mu = p->centres_m;
    double Ts = p->Ts_s, g[MAXP];
    double *a = st->a_N_per_m;
    if (P > MAXP)
        return 1;
    double x = st->x_m, v = st->v_m_per_s;
    double r = in[0];
    double err = r - x;                                   /* x~ = r - x (eq. 65) */
    double g2 = 0.0, kp_prev = 0.0;
    for (i = 0; i < P; i++) {                             /* row of Y(x_k), eq. 62-63 */
        double d = x - mu[i];
        g[i] = p->prefactor * exp(-0.5 * (d * d * p->inv_var_per_m2));
    }
    for (i = 0; i < P; i++)
        g2 += g[i] * g[i];                                /* Y Y^T = |g|^2 */
    for (i = 0; i < P; i++)
        kp_prev += a[i] * g[i];                           /* Y a_k-1 */
    /* eq. 71: a_k = a_k-1 + Ts(-1/tau Y^T (YY^T)^-1 Y a_k-1 + k Y^T |x~_k|) */
    double kp = 0.0;
    for (i = 0; i < P; i++) {
        double forget = g2 > 1e-300 ? kp_prev / g2 * g[i] / p->tau_s : 0.0;
        double ai = a[i] + Ts * (-forget + p->k_N_per_m2s * (fabs(err) * g[i]));
        a[i] = ai < p->a_clamp_N_per_m ? p->a_clamp_N_per_m : ai;  /* per-weight clamp (-inf: none) */
    }
    for (i = 0; i < P; i++)
        kp += a[i] * g[i];                                /* eq. 72 */
    double kpc = kp > 0.0 ? kp : 0.0, kd;
    if (p->physical_damping != 0.0)                      /* damping, eq. 57 / eq. 60 */
        kd = 2.0 * p->xi * sqrt(kpc * p->damping_mass_kg);
    else
        kd = 0.5 * p->xi * sqrt(kpc);
    double derr = st->has_err_prev != 0.0 ? (err - st->err_prev_m) / Ts : 0.0;   /* eq. 74, first sample: 0 */
    st->has_err_prev = 1.0; st->err_prev_m = err;
    double f = st->motors_on != 0.0 ? kp * err + kd * derr : 0.0;   /* eq. 73 */
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
    st->x_m = x; st->v_m_per_s = v;
    return 0;
}

/* n ticks of the kernel above: in (n x (1 + 6 substeps)), out (n x 5). Stops after the
 * tick whose x is not finite or whose |x~| exceeds blowup_m (that row is written, as in
 * the Python loop); returns the number of rows written. */
long cosim_stability_1dof_run(const void *params, void *state, const double *in, double *out,
                              long n, double blowup_m)
{
    const stability_1dof_params *p = params;
    long k, nin = 1 + 6 * (long)p->substeps;
    for (k = 0; k < n; k++) {
        double *o = out + 5 * k;
        if (cosim_kernel_stability_1dof(params, state, in + nin * k, o) != 0)
            return -1;
        if (!isfinite(o[0]) || fabs(o[2]) > blowup_m)
            return k + 1;
    }
    return n;
}
