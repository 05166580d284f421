/* cosim_kernel.h: the C ABI of a controller's compiled step.
 *
 * A class in cosim/algorithms/ may have a compiled twin of its per-tick arithmetic in
 * cosim/algorithms/c/<name>.c, defining
 *
 *     typedef struct { double Ts_s; ... } <name>_params;   parameters, units in the names
 *     typedef struct { double tau_hat_Nm; ... } <name>_state;   state, units in the names
 *     int cosim_kernel_<name>(const void *params, void *state, const double *in, double *out);
 *
 * params  a <name>_params, read-only. The Python class fills the same fields by name:
 *         its ctypes twin (a cosim.algorithms.ckernel.KernelStruct subclass with the
 *         same field names in the same order) in c_kernel() (CKernel.params)
 * state   a <name>_state, read/write, filled the same way (CKernel.state) and read back
 *         by name into the Python object by c_kernel_sync() after a compiled run
 * in      the inputs of this tick in the order of CKernel.inputs
 * out     every output in the order of CKernel.outputs
 *
 * Every field is a double (a flag is 0.0 or 1.0), so that a struct is laid out as the
 * array of doubles the engine keeps (tests/test_kernels.py checks the field names of
 * both sides). A kernel whose state has a variable length (a map, a table sized by the
 * run) ends its struct with a flexible array member.
 *
 * It returns 0, or a nonzero code that the class's c_kernel_error(code) turns into
 * the error its Python step() would have raised. The Python class is the reference:
 * a kernel is tested equal to it (bit-identical or 1e-12), it never replaces it.
 * Plain C99 and <math.h> only; no globals, no allocation, no I/O.
 */
#ifndef COSIM_KERNEL_H
#define COSIM_KERNEL_H

typedef int (*cosim_kernel_fn)(const void *params, void *state, const double *in, double *out);

#endif
