/* zero_force.c: compiled step of cosim.algorithms.zero_force.ZeroForceController, the
 * proportional zero-force controller of thesis Fig. 28 (Sec. 2.5.3). Same arithmetic in
 * the same order as ZeroForceController.step (bit-identical, tests/test_kernels.py).
 *
 * in: f_lc or f_hat [N], then i_dob [A] if use_dob, then f_r [N] if use_force_reference
 * out: i_cmd [A], f_cntr [N]
 */
#include "cosim_kernel.h"

typedef struct {                 /* zero_force.ZeroForceParamsC */
    double Kf_p_N_per_N;         /* proportional force gain */
    double Kf_N_per_A;           /* Kt 2 pi/lead */
    double enabled;
    double use_dob;
    double use_force_reference;
    double saturate;
    double i_max_A;
} zero_force_params;

typedef struct {                 /* zero_force.ZeroForceStateC */
    double f_cntr_N;
} zero_force_state;

int cosim_kernel_zero_force(const void *params, void *state, const double *in, double *out)
{
    const zero_force_params *p = params;
    zero_force_state *s = state;
    int j = 1;
    double f_int = in[0];
    double i_cmp = p->use_dob != 0.0 ? in[j++] : 0.0;
    double f_r = p->use_force_reference != 0.0 ? in[j] : 0.0;
    /* Fig. 28: f_cntr = C(s) (f_r - f_int) with C = Kf_p (proportional) */
    s->f_cntr_N = p->enabled != 0.0 ? p->Kf_p_N_per_N * (f_r - f_int) : 0.0;
    double i_c = s->f_cntr_N / p->Kf_N_per_A;                /* F -> torque -> current */
    double i_tot = i_c + i_cmp;                              /* eq. 5: I_tot = I_c + I_cmp */
    if (p->saturate != 0.0) {                /* max(-limit, min(limit, value)) as in Python */
        double m = i_tot < p->i_max_A ? i_tot : p->i_max_A;
        i_tot = m > -p->i_max_A ? m : -p->i_max_A;
    }
    out[0] = i_tot;
    out[1] = s->f_cntr_N;
    return 0;
}
