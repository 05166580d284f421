/* sine_reference.c: compiled step of cosim.algorithms.zero_force.SineReference.
 *
 * p = {amplitude_m, frequency_Hz, offset_m, Ts_s}, s = {k} (tick counter, exact as a
 * double below 2^53), in = {}, out = {x_ref, v_ref, a_ref}.
 * The same operations in the same order as sine_reference() in zero_force.py.
 */
#include <math.h>
#include "cosim_kernel.h"

#ifndef M_PI
#define M_PI 3.14159265358979323846      /* math.pi: the same double */
#endif

int cosim_kernel_sine_reference(const double *p, double *s, const double *in, double *out)
{
    const double A = p[0], f = p[1], off = p[2], Ts = p[3];
    const double t = s[0] * Ts;                    /* self.k * p.Ts_s */
    const double w = 2.0 * M_PI * f;               /* 2.0 * math.pi * frequency_Hz */
    const double sn = sin(w * t), cs = cos(w * t);
    (void)in;
    out[0] = off + A * sn;
    out[1] = A * w * cs;
    out[2] = -A * w * w * sn;
    s[0] += 1.0;
    return 0;
}
