/* nut_spring.c: compiled twin of cosim.gap.effects.base.nut_on_spring_py, the nut of mass m
 * on a spring-damper (k, c) behind a screw of known motion, pushed by an external force
 * and held by a Coulomb guide friction F_n that sticks (Karnopp):
 *
 *     m x'' = k (xs - x) + c (xs' - x') + f - F_n sign(x')     (sliding)
 *     x' = 0 while |k (xs - x) + c xs' + f| <= F_n             (stuck)
 *
 * xs linear within each sample (slope = the sample's speed), f linear too; ``sub``
 * velocity-Verlet steps per sample (the damper's speed predicted; second order: the
 * explicit Euler step it replaces was 6 % off a 45 Hz ring at 20 steps per sample). The same operations in the same order as the
 * Python reference: tested equal to 1e-12 (tests/test_gap_nut_spring.py).
 *
 * out: per sample k, the means over [t_k, t_k+1) of the nut's acceleration a[k] and of
 * the friction force on it fr[k] (the static force while stuck), and the point sample at
 * t_k of the acceleration through the sensor's first-order pole pt[k] (per step the
 * pole's decay ``sensor_decay`` = exp(-h/tau), exact for the acceleration linear over
 * the step; 0: no pole).
 */
#include <math.h>

long cosim_nut_spring_run(const double *xs, const double *f, long n, double ts, double k,
                          double c, double m, double F_n, long sub, double x0, double v0,
                          double sensor_decay, double *a_out, double *fr_out, double *pt_out)
{
    double x = x0, v = v0;
    double h = ts / (double)sub;
    double y = 0.0;                 /* the sensor's low-passed acceleration */
    /* the pole's exact step for an input linear over the step: y += (1-d)(a0 - y) + g (a1 - a0) */
    double g = sensor_decay > 0.0 ? 1.0 - (1.0 - sensor_decay) / (-log(sensor_decay)) : 1.0;
    int first = 1;
    for (long i = 0; i < n; i++) {
        double xk = xs[i];
        double vs = (i + 1 < n) ? (xs[i + 1] - xs[i]) / ts : (n > 1 ? (xs[i] - xs[i - 1]) / ts : 0.0);
        double fk = f[i];
        double df = (i + 1 < n) ? (f[i + 1] - f[i]) : 0.0;
        double asum = 0.0, fsum = 0.0;
        for (long j = 0; j < sub; j++) {
            double frac0 = (double)j / (double)sub, frac1 = (double)(j + 1) / (double)sub;
            double s0 = xk + vs * ((double)j * h), s1 = xk + vs * ((double)(j + 1) * h);
            double f0 = fk + df * frac0, f1 = fk + df * frac1;
            double F0 = k * (s0 - x) + c * (vs - v) + f0;
            double a0, a1, fr, vn;
            if (v == 0.0 && fabs(F0) <= F_n) {
                /* stuck: stays put; the static friction holds the spring, damper and force */
                a0 = a1 = 0.0;
                vn = 0.0;
                fr = 0.5 * (F0 + (k * (s1 - x) + c * vs + f1));
            } else {
                /* sliding: velocity Verlet with the damper's speed predicted */
                double sg = (v != 0.0) ? (v > 0.0 ? 1.0 : -1.0) : (F0 > 0.0 ? 1.0 : -1.0);
                fr = F_n * sg;
                a0 = (F0 - fr) / m;
                double x1 = x + h * v + 0.5 * h * h * a0;
                double F1 = k * (s1 - x1) + c * (vs - (v + h * a0)) + f1;
                a1 = (F1 - fr) / m;
                vn = v + 0.5 * h * (a0 + a1);
                if (vn * sg < 0.0) {
                    /* its speed crosses zero inside the step, at the fraction th: there it
                     * sticks if the spring, damper and force stay within F_n, else it slides
                     * on the other way for the rest of the step */
                    double th = v / (v - vn);
                    double ht = th * h;
                    double xc = x + ht * v + 0.5 * ht * ht * a0;
                    double Fc = k * (xk + vs * (((double)j + th) * h) - xc) + c * vs + (f0 + df * th / (double)sub);
                    if (fabs(Fc) <= F_n) {
                        vn = 0.0;
                        a1 = 0.0;
                        x1 = xc;
                    } else {
                        double sg2 = Fc > 0.0 ? 1.0 : -1.0;
                        double ar = (Fc - F_n * sg2) / m;
                        double hr = h - ht;
                        vn = hr * ar;
                        a1 = ar;
                        x1 = xc + 0.5 * hr * hr * ar;
                    }
                }
                x = x1;
            }
            asum += (vn - v) / h;
            fsum += fr;
            v = vn;
            if (first) {
                y = a0;
                first = 0;
                pt_out[0] = a0;
            }
            y += (1.0 - sensor_decay) * (a0 - y) + g * (a1 - a0);
        }
        a_out[i] = asum / (double)sub;
        fr_out[i] = fsum / (double)sub;
        if (i + 1 < n)
            pt_out[i + 1] = y;
    }
    return 0;
}
