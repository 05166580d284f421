/* The per-sample loop of cosim/gap/fmu_me.py (MePlant._pass, its reference in Python):
 * a Model Exchange FMU evaluated point-wise along a measured motion, through the FMU's own
 * fmi2 functions (their addresses passed in), with at most one internal state integrated
 * by linearly implicit Euler. Same calls in the same order and the same arithmetic as the
 * Python loop (compiled without FMA contraction), so the results are bit-identical; what
 * it removes is the ~1 us of ctypes per call, 5-9 calls per sample.
 */
#include <stddef.h>

typedef int (*fmi2SetTime_t)(void *, double);
typedef int (*fmi2SetContinuousStates_t)(void *, const double *, size_t);
typedef int (*fmi2GetDerivatives_t)(void *, double *, size_t);
typedef int (*fmi2SetReal_t)(void *, const unsigned int *, size_t, const double *);
typedef int (*fmi2GetReal_t)(void *, const unsigned int *, size_t, double *);

/* fns: fmi2SetTime, fmi2SetContinuousStates, fmi2GetDerivatives, fmi2SetReal, fmi2GetReal.
 * x (n x nx, row-major) is read, and with m == 1 its column j0 is written (the internal
 * state); u, u2 (n x ni; u2 may be NULL: outputs read with u); dx (n x nx), y (n x no)
 * are written; dp: nx doubles of scratch. m: 0 (no internal state) or 1 (state j0, scale
 * sc0). Returns the bitwise OR of the fmi2 status codes of the per-sample calls (as the
 * Python loop: the Jacobian's perturbation calls are not counted). */
int gap_me_points(void *c, void **fns, long n, long nx, long ni, long no,
                  const double *t, double *x, const double *u, const double *u2,
                  const unsigned int *vin, const unsigned int *vout,
                  double *dx, double *y, long m, long j0, double sc0, double *dp)
{
    fmi2SetTime_t st = (fmi2SetTime_t)fns[0];
    fmi2SetContinuousStates_t sx = (fmi2SetContinuousStates_t)fns[1];
    fmi2GetDerivatives_t gd = (fmi2GetDerivatives_t)fns[2];
    fmi2SetReal_t sr = (fmi2SetReal_t)fns[3];
    fmi2GetReal_t gr = (fmi2GetReal_t)fns[4];
    int bad = 0;
    for (long k = 0; k < n; k++) {
        bad |= st(c, t[k]);
        bad |= sx(c, x + k * nx, (size_t)nx);
        if (ni)
            bad |= sr(c, vin, (size_t)ni, u + k * ni);
        bad |= gd(c, dx + k * nx, (size_t)nx);
        if (no) {
            if (u2 && ni)
                bad |= sr(c, vin, (size_t)ni, u2 + k * ni);
            bad |= gr(c, vout, (size_t)no, y + k * no);
            if (u2 && ni)
                bad |= sr(c, vin, (size_t)ni, u + k * ni);
        }
        if (k + 1 == n)
            break;
        if (m == 0)
            continue;
        {
            double h = t[k + 1] - t[k];
            long i1 = (k + 1) * nx + j0;
            double z = x[k * nx + j0];
            double az, mz, dz, f0, jac;
            x[i1] = z;
            sx(c, x + (k + 1) * nx, (size_t)nx);
            gd(c, dp, (size_t)nx);
            f0 = dp[j0];
            az = z < 0.0 ? -z : z;
            mz = (sc0 > az) ? sc0 : az;          /* Python's max(abs(z), sc0) */
            dz = 1e-6 * mz;
            x[i1] = z + dz;
            sx(c, x + (k + 1) * nx, (size_t)nx);
            gd(c, dp, (size_t)nx);
            jac = (dp[j0] - f0) / dz;
            if (jac > 0.0)                       /* only decaying modes are stiff */
                jac = 0.0;
            x[i1] = z + h * f0 / (1.0 - h * jac);
        }
    }
    return bad;
}
