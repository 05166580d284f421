/* cosim_kernel.h: the C ABI of a controller's compiled step.
 *
 * A class in cosim/algorithms/ may have a compiled twin of its per-tick arithmetic in
 * cosim/algorithms/c/<name>.c, defining
 *
 *     int cosim_kernel_<name>(const double *p, double *s, const double *in, double *out);
 *
 * p    parameters, read-only, packed by the class's c_kernel() (CKernel.params)
 * s    state, read/write, packed by c_kernel() (CKernel.state), written back into the
 *      Python object by c_kernel_sync() after a compiled run
 * in   the inputs of this tick in the order of CKernel.inputs
 * out  every output in the order of CKernel.outputs
 *
 * It returns 0, or a nonzero code that the class's c_kernel_error(code) turns into
 * the error its Python step() would have raised. The Python class is the reference:
 * a kernel is tested equal to it (bit-identical or 1e-12), it never replaces it.
 * Plain C99 and <math.h> only; no globals, no allocation, no I/O.
 */
#ifndef COSIM_KERNEL_H
#define COSIM_KERNEL_H

typedef int (*cosim_kernel_fn)(const double *p, double *s, const double *in, double *out);

#endif
