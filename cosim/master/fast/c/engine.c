/* engine.c: the master's compiled tick engine (CPython extension _cosim_engine).
 *
 * It executes a "program" that cosim/master/fast/engine.py prepares from the master's plan
 * (cosim/master/system.py): the same operations, in the same order and with the same
 * double arithmetic, as the Python tick loop (cosim/master/loop.py, TickLoop.run), so
 * that the results are bit-identical. Two modes:
 *
 *   whole loop  run(k0, N): FMU reads into V, precomputed stimuli, compiled controller
 *               steps (cosim_kernel.h), non-finite checks, recording into a
 *               preallocated array, writes (affine unit conversion), sequential
 *               inputs and doSteps, for ticks k0..N in one call;
 *   per tick    read(k) and write_step(k): the FMI calls of one tick, values taken
 *               from and put into the Python loop's list V (Python controllers run
 *               in between).
 *
 * A failure (status > 1, a non-finite value, a kernel's error code) stops the call
 * with 1 and leaves (code, tick, index, status) in Program.error: the Python side
 * raises the error the Python loop would have raised (its fail_* methods).
 * -1: a Python exception is set. Nothing is global; a Program owns copies of its
 * tables and pointers to buffers the Python side keeps alive.
 *
 * Flags: cosim.algorithms.ckernel.CFLAGS (IEEE doubles, no FMA contraction).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "cosim_kernel.h"

/* the kernels linked into this module: generated table (engine.py) */
typedef struct { const char *name; cosim_kernel_fn fn; } kernel_entry;
extern const kernel_entry cosim_kernel_table[];
extern const int cosim_kernel_count;

typedef int (*get2_t)(void *, const uint32_t *, size_t, double *);
typedef int (*get3_t)(void *, const uint32_t *, size_t, double *, size_t);
typedef int (*set2_t)(void *, const uint32_t *, size_t, const double *);
typedef int (*set3_t)(void *, const uint32_t *, size_t, const double *, size_t);
typedef int (*step2_t)(void *, double, double, int);
typedef int (*setder2_t)(void *, const uint32_t *, size_t, const int *, const double *);
typedef int (*step3_t)(void *, double, double, bool, bool *, bool *, bool *, double *);

enum { E_GET = 1, E_SET = 2, E_STEP = 3, E_STIM = 4, E_NONFINITE_IN = 5, E_KERNEL = 6,
       E_NONFINITE_CTRL = 7 };
/* the row buffer's header fields and calls (cosim/master/rows.py: ROWS, ROLE, CALL) */
enum { S_ROWS = 0, S_ROLE = 1, S_CALL = 2 };
enum { C_NONE = 0, C_GET = 1, C_SET = 2, C_STEP = 3 };

typedef struct { int64_t src; int has_gain, has_off; double gain, off; } Term;

typedef struct {            /* one sequential (Gauss-Seidel) input */
    int64_t si; void *get; void *comp; int fmi3; uint32_t vr; Term t;
} Seq;

typedef struct {
    void *comp; int fmi3; void *get, *set, *step;
    int64_t nr; uint32_t *rvr; double *rb; int64_t ra;      /* reads into V[ra:ra+nr] */
    int64_t nw; uint32_t *wvr; double *wb; Term *wt;        /* inputs of the tick */
    int64_t nd; void *setder; int64_t *dp;                   /* interpolated inputs: */
    uint32_t *dvr; int *dord; double *db;                    /* wt[dp[i]], their slopes */
    int64_t ns; uint32_t *svr; double *sb; Seq *sq;         /* sequential inputs */
    int64_t d; double h, tcoff;                             /* step multiple */
    bool *ev, *term, *early; double *last;                  /* FMI 3 out-arguments */
    double step_s;                                          /* time_steps: doStep wall time */
} Fmu;

typedef struct {
    cosim_kernel_fn fn; double *p, *s, *in, *out;
    int64_t nin; int64_t *in_slot;
    int64_t nuse; int64_t *use_idx, *use_slot;              /* out[use_idx] -> V[use_slot] */
} Ctrl;

typedef struct {
    PyObject_HEAD
    int64_t nslot, t0zero, nfmu, nctrl, stim0, nstim, stim_end, ctrl_end, ncol;
    int64_t stim_fail, rows_cap, nrows, time_steps;
    double Ts, T0;
    double *V;              /* whole loop: the values; per tick: scratch */
    double *S;              /* stimuli, (N+1) x nstim */
    double *rows;           /* rows_cap x ncol: the run's row buffer (cosim/master/rows.py) */
    int64_t *status;        /* its header: rows recorded, FMU being called, which call */
    int64_t *rec;           /* slot of each recorded column */
    Fmu *f; Ctrl *c;
    PyObject *Vlist;        /* per tick: the Python loop's list V */
    PyObject *keep;         /* the Python objects owning V, S, rows, p, s */
    int64_t err[4];
} Program;

/* ------------------------------------------------------------------ helpers */
static inline double tick_time(const Program *P, int64_t k)
{   /* as the Python loop: k * Ts, or T0 + k * Ts */
    return P->t0zero ? (double)k * P->Ts : P->T0 + (double)k * P->Ts;
}

static inline double affine(double x, const Term *c)
{   /* as system._affine: x * gain + offset, each only when it is not the identity */
    if (c->has_gain) x = x * c->gain;
    if (c->has_off) x = x + c->off;
    return x;
}

static inline void calling(Program *P, int64_t j, int64_t call)
{   /* where the loop is, for a supervisor reading the row buffer of a dead process */
    P->status[S_ROLE] = j; P->status[S_CALL] = call;
}

static inline int fail(Program *P, int64_t code, int64_t k, int64_t who, int64_t st)
{
    P->err[0] = code; P->err[1] = k; P->err[2] = who; P->err[3] = st;
    return 1;
}

static inline int fmu_get(void *fn, int fmi3, void *comp, const uint32_t *vr, size_t n, double *b)
{
    return fmi3 ? ((get3_t)fn)(comp, vr, n, b, n) : ((get2_t)fn)(comp, vr, n, b);
}

static inline int fmu_set(void *fn, int fmi3, void *comp, const uint32_t *vr, size_t n,
                          const double *b)
{
    return fmi3 ? ((set3_t)fn)(comp, vr, n, b, n) : ((set2_t)fn)(comp, vr, n, b);
}

/* value of slot i: the double V (whole loop) or the Python list (per tick) */
static inline int value_of(Program *P, int64_t i, double *x)
{
    if (!P->Vlist) { *x = P->V[i]; return 0; }
    PyObject *o = PyList_GET_ITEM(P->Vlist, i);
    if (PyFloat_CheckExact(o)) { *x = PyFloat_AS_DOUBLE(o); return 0; }
    *x = PyFloat_AsDouble(o);
    return (*x == -1.0 && PyErr_Occurred()) ? -1 : 0;
}

/* ------------------------------------------------------------------ tick phases */
static int do_reads(Program *P, int64_t k)
{
    for (int64_t j = 0; j < P->nfmu; j++) {
        Fmu *F = &P->f[j];
        if (!F->nr) continue;
        double *dst = P->Vlist ? F->rb : P->V + F->ra;
        calling(P, j, C_GET);
        int st = fmu_get(F->get, F->fmi3, F->comp, F->rvr, (size_t)F->nr, dst);
        if (st > 1) return fail(P, E_GET, k, j, st);
        if (P->Vlist) {
            for (int64_t i = 0; i < F->nr; i++) {
                PyObject *o = PyFloat_FromDouble(dst[i]);
                if (!o) return -1;
                PyList_SetItem(P->Vlist, F->ra + i, o);     /* steals o */
            }
        }
    }
    calling(P, -1, C_NONE);
    return 0;
}

static int do_writes(Program *P, int64_t k)
{
    for (int64_t j = 0; j < P->nfmu; j++) {
        Fmu *F = &P->f[j];
        if (!F->nw || (F->d > 1 && k % F->d)) continue;
        for (int64_t i = 0; i < F->nw; i++) {
            double x;
            if (value_of(P, F->wt[i].src, &x)) return -1;
            F->wb[i] = affine(x, &F->wt[i]);
        }
        calling(P, j, C_SET);
        int st = fmu_set(F->set, F->fmi3, F->comp, F->wvr, (size_t)F->nw, F->wb);
        if (st > 1) return fail(P, E_SET, k, j, st);
        if (F->nd) {
            /* as loop.TickLoop.set_slopes: (x_k+1 - x_k) / Ts from the precomputed
               stimuli; 0 where x_k+1 is not there or not finite (tick k + 1 reports it) */
            const double *S1 = P->S + (k + 1) * P->nstim;
            for (int64_t i = 0; i < F->nd; i++) {
                const Term *t = &F->wt[F->dp[i]];
                double dx = (k + 1 == P->stim_fail) ? 0.0
                            : (affine(S1[t->src - P->stim0], t) - F->wb[F->dp[i]]) / P->Ts;
                F->db[i] = isfinite(dx) ? dx : 0.0;
            }
            st = ((setder2_t)F->setder)(F->comp, F->dvr, (size_t)F->nd, F->dord, F->db);
            if (st > 1) return fail(P, E_SET, k, j, st);
        }
    }
    calling(P, -1, C_NONE);
    return 0;
}

/* the sequential inputs and doSteps of tick k of the FMUs after j0 */
static int do_steps(Program *P, int64_t k, int64_t j0)
{
    double t = tick_time(P, k);
    for (int64_t j = j0 + 1; j < P->nfmu; j++) {
        Fmu *F = &P->f[j];
        if (F->d > 1 && (k + 1) % F->d) continue;
        if (F->ns) {
            for (int64_t q = 0; q < F->ns; q++) {
                Seq *s = &F->sq[q];
                double b;
                calling(P, s->si, C_GET);
                int st = fmu_get(s->get, s->fmi3, s->comp, &s->vr, 1, &b);
                if (st > 1) return fail(P, E_GET, k, s->si, st);
                F->sb[q] = affine(b, &s->t);
            }
            calling(P, j, C_SET);
            int st = fmu_set(F->set, F->fmi3, F->comp, F->svr, (size_t)F->ns, F->sb);
            if (st > 1) return fail(P, E_SET, k, j, st);
        }
        double tc = F->d > 1 ? t - F->tcoff : t;
        struct timespec a, b;
        if (P->time_steps) clock_gettime(CLOCK_MONOTONIC, &a);
        calling(P, j, C_STEP);
        int st, stop;
        if (F->fmi3) {
            st = ((step3_t)F->step)(F->comp, tc, F->h, true, F->ev, F->term, F->early, F->last);
            stop = st > 1 || *F->term || *F->early;
        } else {
            st = ((step2_t)F->step)(F->comp, tc, F->h, 1);
            stop = st > 1;
        }
        if (P->time_steps) {
            clock_gettime(CLOCK_MONOTONIC, &b);
            F->step_s += (double)(b.tv_sec - a.tv_sec) + 1e-9 * (double)(b.tv_nsec - a.tv_nsec);
        }
        if (stop) return fail(P, E_STEP, k, j, st);
    }
    calling(P, -1, C_NONE);
    return 0;
}

static int run_loop(Program *P, int64_t k0, int64_t N)
{
    double *V = P->V;
    int r;
    P->nrows = k0;              /* row k is at its place: row k0 follows rows 0..k0-1 */
    for (int64_t k = k0; k <= N; k++) {
        if (!((k - k0 + 1) & 4095) && PyErr_CheckSignals()) return -1;
        V[0] = tick_time(P, k);
        if ((r = do_reads(P, k))) return r;
        if (P->nstim) {
            if (k == P->stim_fail) return fail(P, E_STIM, k, -1, 0);
            memcpy(V + P->stim0, P->S + k * P->nstim, (size_t)P->nstim * sizeof(double));
        }
        for (int64_t i = 1; i < P->stim_end; i++)
            if (!isfinite(V[i])) return fail(P, E_NONFINITE_IN, k, i, 0);
        for (int64_t i = 0; i < P->nctrl; i++) {
            Ctrl *C = &P->c[i];
            for (int64_t q = 0; q < C->nin; q++) C->in[q] = V[C->in_slot[q]];
            int rc = C->fn(C->p, C->s, C->in, C->out);
            if (rc) return fail(P, E_KERNEL, k, i, rc);
            for (int64_t q = 0; q < C->nuse; q++) V[C->use_slot[q]] = C->out[C->use_idx[q]];
        }
        for (int64_t i = P->stim_end; i < P->ctrl_end; i++)
            if (!isfinite(V[i])) return fail(P, E_NONFINITE_CTRL, k, i, 0);
        if (P->nrows < P->rows_cap) {
            double *row = P->rows + P->nrows * P->ncol;
            for (int64_t i = 0; i < P->ncol; i++) row[i] = V[P->rec[i]];
            P->nrows++;
            P->status[S_ROWS] = P->nrows;
        }
        if (k == N) break;
        if ((r = do_writes(P, k))) return r;
        if ((r = do_steps(P, k, -1))) return r;
    }
    return 0;
}

/* ------------------------------------------------------------------ construction */
typedef struct { const int64_t *i; Py_ssize_t ni, pi; const double *d; Py_ssize_t nd, pd; int bad; } Cur;

static int64_t I(Cur *c) { if (c->pi >= c->ni) { c->bad = 1; return 0; } return c->i[c->pi++]; }
static double D(Cur *c) { if (c->pd >= c->nd) { c->bad = 1; return 0; } return c->d[c->pd++]; }
static void *A(Cur *c) { return (void *)(intptr_t)I(c); }

static void *zalloc(int64_t n, size_t size) { return calloc((size_t)(n > 0 ? n : 1), size); }

/* a slot index: in [0, n) or the layout is malformed */
static int64_t SLOT(Cur *c, int64_t n)
{
    int64_t x = I(c);
    if (x < 0 || x >= n) c->bad = 1;
    return x;
}

static void read_term(Cur *c, Term *t, int64_t nslot)
{
    t->src = SLOT(c, nslot); t->has_gain = (int)I(c); t->has_off = (int)I(c);
    t->gain = D(c); t->off = D(c);
}

static void Program_free_tables(Program *P)
{
    if (P->f) {
        for (int64_t j = 0; j < P->nfmu; j++) {
            Fmu *F = &P->f[j];
            free(F->rvr); free(F->rb); free(F->wvr); free(F->wb); free(F->wt);
            free(F->svr); free(F->sb); free(F->sq);
            free(F->dp); free(F->dvr); free(F->dord); free(F->db);
        }
        free(P->f); P->f = NULL;
    }
    if (P->c) {
        for (int64_t i = 0; i < P->nctrl; i++) {
            Ctrl *C = &P->c[i];
            free(C->in); free(C->out); free(C->in_slot); free(C->use_idx); free(C->use_slot);
        }
        free(P->c); P->c = NULL;
    }
    free(P->rec); P->rec = NULL;
}

static void Program_dealloc(Program *P)
{
    Program_free_tables(P);
    Py_XDECREF(P->Vlist);
    Py_XDECREF(P->keep);
    Py_TYPE(P)->tp_free((PyObject *)P);
}

static cosim_kernel_fn find_kernel(const char *name)
{
    for (int i = 0; i < cosim_kernel_count; i++)
        if (!strcmp(cosim_kernel_table[i].name, name)) return cosim_kernel_table[i].fn;
    return NULL;
}

/* Program(ints, doubles, kernel_names, Vlist_or_None, keep): the layout is written by
 * cosim/master/fast/engine.py (_Layout) and read here in the same order. */
static int Program_init(Program *P, PyObject *args, PyObject *kw)
{
    (void)kw;
    Py_buffer bi, bd;
    PyObject *names, *Vlist, *keep;
    if (!PyArg_ParseTuple(args, "y*y*O!OO", &bi, &bd, &PyTuple_Type, &names, &Vlist, &keep))
        return -1;
    Cur c = { bi.buf, bi.len / 8, 0, bd.buf, bd.len / 8, 0, 0 };
    int ok = 0;
    Program_free_tables(P);
    P->nslot = I(&c); P->t0zero = I(&c); P->nfmu = I(&c); P->nctrl = I(&c);
    P->stim0 = I(&c); P->nstim = I(&c); P->stim_end = I(&c); P->ctrl_end = I(&c);
    P->ncol = I(&c); P->stim_fail = I(&c); P->rows_cap = I(&c); P->nrows = 0;
    P->V = A(&c); P->S = A(&c); P->rows = A(&c); P->status = A(&c);
    if (!P->status) c.bad = 1;
    P->Ts = D(&c); P->T0 = D(&c);
    P->f = zalloc(P->nfmu, sizeof(Fmu));
    P->c = zalloc(P->nctrl, sizeof(Ctrl));
    P->rec = zalloc(P->ncol, sizeof(int64_t));
    for (int64_t j = 0; j < P->nfmu && !c.bad; j++) {
        Fmu *F = &P->f[j];
        F->comp = A(&c); F->fmi3 = (int)I(&c); F->get = A(&c); F->set = A(&c); F->step = A(&c);
        F->nr = I(&c); F->ra = I(&c);
        if (F->nr < 0 || (F->nr && (F->ra < 1 || F->ra + F->nr > P->nslot))) c.bad = 1;
        F->rvr = zalloc(F->nr, sizeof(uint32_t)); F->rb = zalloc(F->nr, sizeof(double));
        for (int64_t i = 0; i < F->nr; i++) F->rvr[i] = (uint32_t)I(&c);
        F->nw = I(&c);
        if (F->nw < 0) c.bad = 1;
        F->wvr = zalloc(F->nw, sizeof(uint32_t)); F->wb = zalloc(F->nw, sizeof(double));
        F->wt = zalloc(F->nw, sizeof(Term));
        for (int64_t i = 0; i < F->nw; i++) { F->wvr[i] = (uint32_t)I(&c); read_term(&c, &F->wt[i], P->nslot); }
        F->nd = I(&c); F->setder = A(&c);
        if (F->nd < 0 || F->nd > F->nw || (F->nd && (!F->setder || F->fmi3 || !P->S))) c.bad = 1;
        F->dp = zalloc(F->nd, sizeof(int64_t)); F->dvr = zalloc(F->nd, sizeof(uint32_t));
        F->dord = zalloc(F->nd, sizeof(int)); F->db = zalloc(F->nd, sizeof(double));
        for (int64_t i = 0; i < F->nd && !c.bad; i++) {
            F->dp[i] = I(&c);
            if (F->dp[i] < 0 || F->dp[i] >= F->nw) { c.bad = 1; break; }
            int64_t src = F->wt[F->dp[i]].src;     /* a stimulus' slot */
            if (src < P->stim0 || src >= P->stim0 + P->nstim) c.bad = 1;
            F->dvr[i] = F->wvr[F->dp[i]]; F->dord[i] = 1;
        }
        F->ns = I(&c);
        if (F->ns < 0) c.bad = 1;
        F->svr = zalloc(F->ns, sizeof(uint32_t)); F->sb = zalloc(F->ns, sizeof(double));
        F->sq = zalloc(F->ns, sizeof(Seq));
        for (int64_t q = 0; q < F->ns; q++) {
            Seq *s = &F->sq[q];
            F->svr[q] = (uint32_t)I(&c);
            s->si = I(&c); s->get = A(&c); s->comp = A(&c); s->fmi3 = (int)I(&c);
            s->vr = (uint32_t)I(&c); read_term(&c, &s->t, P->nslot);
            if (s->si < 0 || s->si >= j) c.bad = 1;       /* a source stepped before j */
        }
        F->d = I(&c); F->h = D(&c); F->tcoff = D(&c);
        F->ev = A(&c); F->term = A(&c); F->early = A(&c); F->last = A(&c);
        if (!F->comp || !F->step || (F->nr && !F->get) || ((F->nw || F->ns) && !F->set) ||
            F->d < 1 || (F->fmi3 && !(F->ev && F->term && F->early && F->last)))
            c.bad = 1;
    }
    for (int64_t i = 0; i < P->nctrl && !c.bad; i++) {
        Ctrl *C = &P->c[i];
        PyObject *nm = PyTuple_GetItem(names, i);
        const char *s = nm ? PyUnicode_AsUTF8(nm) : NULL;
        if (!s) goto done;
        C->fn = find_kernel(s);
        if (!C->fn) { PyErr_Format(PyExc_KeyError, "no compiled step %R in this engine", nm); goto done; }
        C->p = A(&c); C->s = A(&c);
        C->nin = I(&c);
        if (C->nin < 0) c.bad = 1;
        C->in = zalloc(C->nin, sizeof(double)); C->in_slot = zalloc(C->nin, sizeof(int64_t));
        for (int64_t q = 0; q < C->nin; q++) C->in_slot[q] = SLOT(&c, P->nslot);
        int64_t nout = I(&c);
        C->out = zalloc(nout, sizeof(double));
        C->nuse = I(&c);
        if (C->nuse < 0) c.bad = 1;
        C->use_idx = zalloc(C->nuse, sizeof(int64_t)); C->use_slot = zalloc(C->nuse, sizeof(int64_t));
        for (int64_t q = 0; q < C->nuse; q++) {
            C->use_idx[q] = I(&c); C->use_slot[q] = SLOT(&c, P->nslot);
            if (C->use_idx[q] < 0 || C->use_idx[q] >= nout) c.bad = 1;
        }
    }
    for (int64_t i = 0; i < P->ncol; i++) P->rec[i] = SLOT(&c, P->nslot);
    if (P->nslot < 1 || P->stim0 < 1 || P->stim0 + P->nstim > P->nslot ||
        P->stim_end > P->nslot || P->ctrl_end > P->nslot || P->stim_end > P->ctrl_end)
        c.bad = 1;
    if (!c.bad && c.pi != c.ni) c.bad = 1;
    if (c.bad) { PyErr_SetString(PyExc_ValueError, "engine program: malformed layout"); goto done; }
    if (Vlist != Py_None) {
        if (!PyList_CheckExact(Vlist) || PyList_GET_SIZE(Vlist) != P->nslot) {
            PyErr_SetString(PyExc_TypeError, "engine program: V must be a list of nslot values");
            goto done;
        }
        Py_INCREF(Vlist); Py_XSETREF(P->Vlist, Vlist);
    } else if (!P->V || (P->ncol && !P->rows) || (P->nstim && !P->S)) {
        PyErr_SetString(PyExc_ValueError, "engine program: whole loop without buffers");
        goto done;
    }
    Py_INCREF(keep); Py_XSETREF(P->keep, keep);
    ok = 1;
done:
    PyBuffer_Release(&bi); PyBuffer_Release(&bd);
    if (!ok) { Program_free_tables(P); return -1; }
    return 0;
}

/* ------------------------------------------------------------------ methods */
static PyObject *result(int r)
{
    if (r < 0) return NULL;
    return PyLong_FromLong(r);
}

static PyObject *Program_run(Program *P, PyObject *args)
{
    long long k0, N;
    if (!PyArg_ParseTuple(args, "LL", &k0, &N)) return NULL;
    if (P->Vlist) { PyErr_SetString(PyExc_RuntimeError, "run(): a per-tick program"); return NULL; }
    if (k0 < 0 || N >= P->rows_cap || k0 > N + 1) {
        PyErr_SetString(PyExc_ValueError, "run(): ticks out of range"); return NULL;
    }
    return result(run_loop(P, k0, N));
}

static PyObject *Program_read(Program *P, PyObject *arg)
{
    long long k = PyLong_AsLongLong(arg);
    if (k == -1 && PyErr_Occurred()) return NULL;
    return result(do_reads(P, k));
}

static PyObject *Program_write_step(Program *P, PyObject *arg)
{
    long long k = PyLong_AsLongLong(arg);
    if (k == -1 && PyErr_Occurred()) return NULL;
    int r = do_writes(P, k);
    if (!r) r = do_steps(P, k, -1);
    return result(r);
}

static PyObject *Program_steps(Program *P, PyObject *args)
{
    long long k, j0;
    if (!PyArg_ParseTuple(args, "LL", &k, &j0)) return NULL;
    return result(do_steps(P, k, j0));
}

static PyObject *Program_get_error(Program *P, void *closure)
{
    return Py_BuildValue("(LLLL)", (long long)P->err[0], (long long)P->err[1],
                         (long long)P->err[2], (long long)P->err[3]);
}

static PyObject *Program_get_nrows(Program *P, void *closure)
{
    return PyLong_FromLongLong(P->nrows);
}

static PyObject *Program_get_stim_fail(Program *P, void *closure)
{
    return PyLong_FromLongLong(P->stim_fail);
}

static int Program_set_stim_fail(Program *P, PyObject *v, void *closure)
{
    long long k = v ? PyLong_AsLongLong(v) : -1;
    if (k == -1 && PyErr_Occurred()) return -1;
    P->stim_fail = k;
    return 0;
}

static PyObject *Program_get_step_seconds(Program *P, void *closure)
{
    (void)closure;
    PyObject *t = PyTuple_New(P->nfmu);
    if (!t) return NULL;
    for (int64_t j = 0; j < P->nfmu; j++) {
        PyObject *x = PyFloat_FromDouble(P->f[j].step_s);
        if (!x) { Py_DECREF(t); return NULL; }
        PyTuple_SET_ITEM(t, j, x);
    }
    return t;
}

static PyObject *Program_get_time_steps(Program *P, void *closure)
{
    (void)closure;
    return PyBool_FromLong((long)P->time_steps);
}

static int Program_set_time_steps(Program *P, PyObject *v, void *closure)
{
    (void)closure;
    int on = v ? PyObject_IsTrue(v) : 0;
    if (on < 0) return -1;
    P->time_steps = on;
    return 0;
}

static PyMethodDef Program_methods[] = {
    {"run", (PyCFunction)Program_run, METH_VARARGS,
     "run(k0, N) -> 0 | 1: ticks k0..N of the whole loop (1: failed, see error)"},
    {"read", (PyCFunction)Program_read, METH_O, "read(k) -> 0 | 1: the FMU reads of tick k into V"},
    {"write_step", (PyCFunction)Program_write_step, METH_O,
     "write_step(k) -> 0 | 1: the inputs and doSteps of tick k"},
    {"steps", (PyCFunction)Program_steps, METH_VARARGS,
     "steps(k, j0) -> 0 | 1: the sequential inputs and doSteps of tick k after FMU j0"},
    {NULL}
};

static PyGetSetDef Program_getset[] = {
    {"error", (getter)Program_get_error, NULL, "(code, tick, index, status) of the last failure", NULL},
    {"nrows", (getter)Program_get_nrows, NULL, "rows recorded by run()", NULL},
    {"step_seconds", (getter)Program_get_step_seconds, NULL,
     "wall time spent in each FMU's doStep while time_steps was on [s]", NULL},
    {"time_steps", (getter)Program_get_time_steps, (setter)Program_set_time_steps,
     "measure the FMUs' own doStep time (two clock reads per doStep; benchmarks)", NULL},
    {"stim_fail", (getter)Program_get_stim_fail, (setter)Program_set_stim_fail,
     "tick at which a stimulus failed (evaluated beforehand): run() stops there, E_STIM", NULL},
    {NULL}
};

static PyTypeObject ProgramType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "_cosim_engine.Program",
    .tp_basicsize = sizeof(Program),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Program_init,
    .tp_dealloc = (destructor)Program_dealloc,
    .tp_methods = Program_methods,
    .tp_getset = Program_getset,
    .tp_doc = "A tick program of the master (see cosim/master/fast/engine.py).",
};

static PyObject *kernel_names(PyObject *self, PyObject *unused)
{
    PyObject *t = PyTuple_New(cosim_kernel_count);
    if (!t) return NULL;
    for (int i = 0; i < cosim_kernel_count; i++) {
        PyObject *s = PyUnicode_FromString(cosim_kernel_table[i].name);
        if (!s) { Py_DECREF(t); return NULL; }
        PyTuple_SET_ITEM(t, i, s);
    }
    return t;
}

static PyMethodDef module_methods[] = {
    {"kernel_names", kernel_names, METH_NOARGS, "names of the compiled steps linked in"},
    {NULL}
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_cosim_engine", "The master's compiled tick engine.", -1,
    module_methods
};

PyMODINIT_FUNC PyInit__cosim_engine(void)
{
    if (PyType_Ready(&ProgramType) < 0) return NULL;
    PyObject *m = PyModule_Create(&module);
    if (!m) return NULL;
    Py_INCREF(&ProgramType);
    if (PyModule_AddObject(m, "Program", (PyObject *)&ProgramType) < 0) {
        Py_DECREF(&ProgramType); Py_DECREF(m); return NULL;
    }
    PyModule_AddIntConstant(m, "E_GET", E_GET);
    PyModule_AddIntConstant(m, "E_SET", E_SET);
    PyModule_AddIntConstant(m, "E_STEP", E_STEP);
    PyModule_AddIntConstant(m, "E_STIM", E_STIM);
    PyModule_AddIntConstant(m, "E_NONFINITE_IN", E_NONFINITE_IN);
    PyModule_AddIntConstant(m, "E_KERNEL", E_KERNEL);
    PyModule_AddIntConstant(m, "E_NONFINITE_CTRL", E_NONFINITE_CTRL);
    return m;
}
