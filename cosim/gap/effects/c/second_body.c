/* second_body.c: compiled twin of cosim.gap.effects.fmu_form.second_body_py, the sensed body
 * of a plant FMU's structural effects (backlash, compliance): a second body behind the
 * plant's point of known motion, coupled to it by a spring-damper with a dead zone (the
 * play), pushed by an external force and held by a Coulomb guide friction that sticks
 * (Karnopp). All forces per unit mass of the body (accelerations):
 *
 *     d = x_p - x_b,   dz = d - w/2 (d > w/2), d + w/2 (d < -w/2), 0 (in the play)
 *     x_b'' = k dz + c (x_p' - x_b') [dz != 0] + g - mu sign(x_b')     (sliding)
 *     x_b' = 0 while |k dz + c x_p' [dz != 0] + g| <= mu                 (stuck)
 *
 * The point's motion is a cubic per sample interval (x, v, a, jerk: a C2 spline through
 * the measured positions, so that a stiff coupling is not rung by a kink at every sample); g
 * linear within the interval; ``sub`` velocity-Verlet steps per sample (the damper's speed
 * predicted, the body's speed zero crossings located inside the step), as nut_spring.c.
 * The same operations in the same order as the Python reference: tested equal
 * (tests/test_gap_fmu_structural.py).
 *
 * out: per sample k, the mean over [t_k - Ts/2, t_k + Ts/2) of the body's acceleration minus
 * the point's, delta[k], and of the guide friction on the body, fr[k] (the static force while
 * stuck).
 */
#include <math.h>

static double coupling(double d, double dv, double hw, double k, double c)
{
    if (d > hw)
        return k * (d - hw) + c * dv;
    if (d < -hw)
        return k * (d + hw) + c * dv;
    return 0.0;
}

long cosim_second_body_run(const double *xk, const double *vk, const double *ak, const double *jk,
                           const double *g, long n, double ts, double w, double k, double c,
                           double mu, long sub, double *delta, double *fr_out)
{
    double hw = 0.5 * w;
    double h = ts / (double)sub;
    double xb, vb;
    if (n < 2)
        return 0;
    xb = xk[0];
    vb = vk[0];
    for (long i = 0; i < n; i++) {
        delta[i] = 0.0;
        fr_out[i] = 0.0;
    }
    for (long i = 0; i + 1 < n; i++) {
        double X = xk[i], V = vk[i], A = ak[i], J = jk[i];
        double gk = g[i], dg = g[i + 1] - g[i];
        for (long j = 0; j < sub; j++) {
            double t0 = (double)j * h, t1 = (double)(j + 1) * h;
            double xp0 = X + t0 * (V + t0 * (0.5 * A + t0 * J / 6.0));
            double vp0 = V + t0 * (A + 0.5 * J * t0);
            double ap0 = A + J * t0;
            double xp1 = X + t1 * (V + t1 * (0.5 * A + t1 * J / 6.0));
            double vp1 = V + t1 * (A + 0.5 * J * t1);
            double ap1 = A + J * t1;
            double g0 = gk + dg * ((double)j / (double)sub), g1 = gk + dg * ((double)(j + 1) / (double)sub);
            double F0 = coupling(xp0 - xb, vp0 - vb, hw, k, c) + g0;
            double a0, a1, vn, x1, fr;
            if (vb == 0.0 && fabs(F0) <= mu) {
                /* stuck: stays put; the static friction holds the coupling and the force */
                a0 = a1 = 0.0;
                vn = 0.0;
                x1 = xb;
                fr = 0.5 * (F0 + coupling(xp1 - xb, vp1, hw, k, c) + g1);
            } else {
                double sg = (vb != 0.0) ? (vb > 0.0 ? 1.0 : -1.0) : (F0 > 0.0 ? 1.0 : -1.0);
                fr = mu * sg;
                a0 = F0 - fr;
                x1 = xb + h * vb + 0.5 * h * h * a0;
                a1 = coupling(xp1 - x1, vp1 - (vb + h * a0), hw, k, c) + g1 - fr;
                vn = vb + 0.5 * h * (a0 + a1);
                if (mu > 0.0 && vn * sg < 0.0) {
                    /* its speed crosses zero inside the step, at the fraction th: there it
                     * sticks if the coupling and the force stay within mu, else it slides on
                     * the other way for the rest of the step */
                    double th = vb / (vb - vn);
                    double ht = th * h;
                    double xc = xb + ht * vb + 0.5 * ht * ht * a0;
                    double tc = t0 + ht;
                    double xpc = X + tc * (V + tc * (0.5 * A + tc * J / 6.0));
                    double vpc = V + tc * (A + 0.5 * J * tc);
                    double Fc = coupling(xpc - xc, vpc, hw, k, c) + (g0 + (g1 - g0) * th);
                    if (fabs(Fc) <= mu) {
                        vn = 0.0;
                        a1 = 0.0;
                        x1 = xc;
                    } else {
                        double sg2 = Fc > 0.0 ? 1.0 : -1.0;
                        double ar = Fc - mu * sg2;
                        double hr = h - ht;
                        vn = hr * ar;
                        a1 = ar;
                        x1 = xc + 0.5 * hr * hr * ar;
                    }
                }
            }
            /* the step's mean acceleration of the body minus the point's (trapezoid: exact
             * for the point's linear acceleration), into the sample whose centred interval
             * holds the step's centre */
            {
                long b = i + (2 * j + 1 >= sub ? 1 : 0);
                delta[b] += (vn - vb) / h - 0.5 * (ap0 + ap1);
                fr_out[b] += fr;
            }
            xb = x1;
            vb = vn;
        }
    }
    {
        /* the first and the last sample hold half an interval each */
        long half = sub / 2, rest = sub - sub / 2;
        delta[0] /= (double)half;
        fr_out[0] /= (double)half;
        delta[n - 1] /= (double)rest;
        fr_out[n - 1] /= (double)rest;
        for (long i = 1; i + 1 < n; i++) {
            delta[i] /= (double)sub;
            fr_out[i] /= (double)sub;
        }
    }
    return 0;
}
