/* sine_reference.c: compiled step of cosim.algorithms.zero_force.SineReference.
 *
 * in = {}, out = {x_ref, v_ref, a_ref}.
 * The same operations in the same order as sine_reference() in zero_force.py.
 */
#include <math.h>
#include "cosim_kernel.h"

#ifndef M_PI
#define M_PI 3.14159265358979323846      /* math.pi: the same double */
#endif

typedef struct {                 /* zero_force.SineReferenceParamsC */
    double amplitude_m;
    double frequency_Hz;
    double offset_m;
    double Ts_s;
} sine_reference_params;

typedef struct {                 /* zero_force.SineReferenceStateC */
    double k;                    /* tick counter, exact as a double below 2^53 */
} sine_reference_state;

int cosim_kernel_sine_reference(const void *params, void *state, const double *in, double *out)
{
    const sine_reference_params *p = params;
    sine_reference_state *s = state;
    const double A = p->amplitude_m, off = p->offset_m;
    const double t = s->k * p->Ts_s;               /* self.k * p.Ts_s */
    const double w = 2.0 * M_PI * p->frequency_Hz; /* 2.0 * math.pi * frequency_Hz */
    const double sn = sin(w * t), cs = cos(w * t);
    (void)in;
    out[0] = off + A * sn;
    out[1] = A * w * cs;
    out[2] = -A * w * w * sn;
    s->k += 1.0;
    return 0;
}
