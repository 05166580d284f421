/* nut_spring.c: compiled twin of cosim.gap.effects.base.nut_on_spring_py, the nut of mass m
 * on a spring-damper (k, c) behind a screw of known motion, pushed by an external force
 * and held by a Coulomb guide friction F_n that sticks (Karnopp):
 *
 *     m x'' = k (xs - x) + c (xs' - x') + f - F_n sign(x')     (sliding)
 *     x' = 0 while |k (xs - x) + c xs' + f| <= F_n             (stuck)
 *
 * xs linear within each sample (slope = the sample's speed), f linear too; ``sub``
 * semi-implicit Euler steps per sample. The same operations in the same order as the
 * Python reference: tested equal to 1e-12 (tests/test_gap_nut_spring.py).
 *
 * out: per sample k, the means over [t_k, t_k+1) of the nut's acceleration a[k] and of
 * the friction force on it fr[k] (the static force while stuck), and the point sample at
 * t_k of the acceleration through the sensor's first-order pole pt[k] (per step the
 * pole's exact decay ``sensor_decay`` = exp(-h/tau); 0: no pole).
 */
#include <math.h>

long cosim_nut_spring_run(const double *xs, const double *f, long n, double ts, double k,
                          double c, double m, double F_n, long sub, double x0, double v0,
                          double sensor_decay, double *a_out, double *fr_out, double *pt_out)
{
    double x = x0, v = v0;
    double h = ts / (double)sub;
    double y = 0.0;                 /* the sensor's low-passed acceleration */
    int first = 1;
    for (long i = 0; i < n; i++) {
        double xk = xs[i];
        double vs = (i + 1 < n) ? (xs[i + 1] - xs[i]) / ts : (n > 1 ? (xs[i] - xs[i - 1]) / ts : 0.0);
        double fk = f[i];
        double df = (i + 1 < n) ? (f[i + 1] - f[i]) : 0.0;
        double asum = 0.0, fsum = 0.0;
        for (long j = 0; j < sub; j++) {
            double tau = (double)j * h;
            double frac = (double)j / (double)sub;
            double F = k * (xk + vs * tau - x) + c * (vs - v) + (fk + df * frac);
            double a, fr;
            if (v == 0.0 && fabs(F) <= F_n) {
                a = 0.0;
                fr = F;
            } else {
                double sg = (v != 0.0) ? (v > 0.0 ? 1.0 : -1.0) : (F > 0.0 ? 1.0 : -1.0);
                fr = F_n * sg;
                a = (F - fr) / m;
            }
            double vn = v + h * a;
            if (v != 0.0 && vn * v < 0.0)
                vn = 0.0;
            x += h * 0.5 * (v + vn);
            v = vn;
            asum += a;
            fsum += fr;
            if (first) {
                y = a;
                first = 0;
                pt_out[0] = a;
            }
            y += (1.0 - sensor_decay) * (a - y);
        }
        a_out[i] = asum / (double)sub;
        fr_out[i] = fsum / (double)sub;
        if (i + 1 < n)
            pt_out[i + 1] = y;
    }
    return 0;
}
