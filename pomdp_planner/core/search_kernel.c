/*
 * The compiled search kernel of pomdp_planner: Algorithm 1 of the paper (branch-and-bound with
 * myopic policy bounds) and its exhaustive baseline, for the planner of core/search.py.
 *
 * Built by setuptools as the top-level extension module ``_pomdp_planner_kernel`` (setup.py);
 * core/search_kernel.py is its only caller and core/search_reference.py its numpy twin: the
 * two follow the same traversal, step for step (below), and the tests hold them to equal values
 * and node counts. Plain C99 and the CPython C API; arrays arrive through the buffer protocol
 * (no numpy headers, so the build does not depend on numpy's ABI).
 *
 * Conventions (docs/THEORY.md): P[a][i, j] = P(next = j | prev = i, a), O[a][j, z] = P(z | next
 * = j, a), r[s, a], rho(b, a) = r_a . b - cost_a - w_a f(b) (Eq. 3; ``cost`` is the action-only
 * price of Planner.priced, zero otherwise), b^a = b P[a] (Eq. 1), u_z = b^a o O[a][:, z],
 * eta_z = sum u_z, tau = u_z / eta_z (Eq. 2).
 *
 * Traversal (the same in the numpy reference, so that a deadline read from a deterministic
 * clock stops both at the same point): a level's nodes are taken in chunks (``leaf_chunk``
 * parents when the level below is the leaf level, ``expand_chunk`` otherwise); in each chunk the
 * actions in order (the root's ``order``, else 0..A-1); for each action with at least one parent
 * of the chunk allowing it, one *step*: the deadline is read, then the allowed parents' children
 * under that action are formed (parent-major, then observation; branches with eta <= ETA_SKIP are
 * impossible and skipped), valued depth-first by the same rule, and backed up
 * (Q = rho + gamma sum_z eta V). On the leaf-parent level a step values the leaves directly with
 * the fused formulas (no posterior formed):
 *   eta V(leaf) = max_a' (u . r_a' - cost_a' eta - w_a' eta f(u / eta)),
 *   Renyi:   -eta f = eta log(sum_s u_s^2 / eta^2),  sum_s u_s^2 = (b^a)^2 . O[a][:, z]^2
 *   Shannon: -eta f = sum_s u_s log u_s - eta log eta,
 *            sum_s u_s log u_s = (b^a log b^a) . O[a][:, z] + b^a . (O log O)[a][:, z]
 * and leaves with eta < ETA_FUSED_MIN from the normalised posterior (no underflow).
 *
 * Bounds (Eq. 8, core/myopic.py): lower = smallest maximiser of rho + Cg tau, upper = largest
 * maximiser of rho + Ch tau, values within TIE_RTOL (relative) of the maximum counting as ties;
 * lower > upper (crossed) keeps every action. Evaluated once per non-leaf node, when it is formed.
 *
 * P and O are dense (row-major, as numpy holds them) or CSR per action (indptr of A (S + 1)
 * absolute offsets, column indices, values; the table X of O^2 or O log O shares O's pattern).
 * Prediction and the observation products are written once per layout (predict_*,
 * observe_*); everything else is shared.
 */

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <stdint.h>
#include <string.h>
#include <time.h>

#define KERNEL_VERSION 1

#define ETA_SKIP 1e-300
#define ETA_FUSED_MIN 1e-100
#define TIE_RTOL 1e-12
/* Columns of one accumulator tile of the matrix-vector products (gemv_rows): 8, or 4 at the end;
 * the fused leaf table's blocks and the reward and bound products are padded to a multiple of 4. */
#define TILE 8
#define PAD 4

enum { KIND_NONE = 0, KIND_RENYI2 = 1, KIND_SHANNON = 2 };
enum { DONE = 0, INTERRUPTED = 1, FAILED = -1 };

#if defined(__GNUC__)
/* The hot loops' helpers are inlined into each compiled version of their callers (HOT). */
#define INLINE static inline __attribute__((always_inline))
#else
#define INLINE static inline
#endif

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
/* The hot loops are also compiled for AVX2 + FMA; the loader picks the clone the CPU runs. */
#define HOT __attribute__((target_clones("arch=x86-64-v3", "default")))
#else
#define HOT
#endif

/* ------------------------------------------------------------------------ the model tables */

typedef struct {
    PyObject_HEAD
    Py_ssize_t S, A, Z;
    double gamma;
    int kind;
    int p_sparse, o_sparse;
    Py_buffer views[20];
    int nviews;
    const double *w;   /* A */
    const double *r;   /* S x A */
    const double *rT;  /* A x S */
    const double *Cg;  /* A x S, or NULL (no bounds) */
    const double *Ch;  /* A x S, or NULL */
    /* dense */
    const double *P;   /* A x S x S */
    const double *O;   /* A x S x Z */
    const double *OT;  /* A x Z x S */
    const double *X;   /* A x S x Z: O^2 (Renyi) or O log O (Shannon); NULL for none */
    const double *W;   /* A x S x Kw: the fused leaf table (leaf_products), or NULL */
    Py_ssize_t Kw, Zp, nblk; /* Kw = nblk Zp: its blocks, each Z columns padded to Zp (a multiple of TILE) */
    const double *MT;  /* S x NM: [r | Cg^T | Ch^T] (NM = 3 A) or r (NM = A): node_info's products */
    Py_ssize_t NM;
    /* CSR */
    const int64_t *Pp, *Pi; const double *Px;
    const int64_t *Op, *Oi; const double *Ox, *Xx;
} Tables;

static void tables_dealloc(Tables *self)
{
    for (int i = 0; i < self->nviews; i++)
        PyBuffer_Release(&self->views[i]);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

/* A read-only C-contiguous view of ``obj`` holding ``count`` items of format ``fmt`` ("d" or "q"). */
static const void *take_view(Tables *self, PyObject *obj, const char *fmt, Py_ssize_t count, const char *name)
{
    Py_buffer *v = &self->views[self->nviews];
    if (PyObject_GetBuffer(obj, v, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
        return NULL;
    self->nviews++;
    const char *f = v->format ? v->format : "B";
    if (f[0] == '<' || f[0] == '=' || f[0] == '@')
        f++;
    int ok = fmt[0] == 'd' ? (f[0] == 'd' && v->itemsize == 8)
                           : ((f[0] == 'q' || f[0] == 'l') && v->itemsize == 8);
    if (!ok || f[1] != '\0') {
        PyErr_Format(PyExc_TypeError, "%s: expected %s items", name, fmt[0] == 'd' ? "float64" : "int64");
        return NULL;
    }
    if (v->len != count * 8) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd items, got %zd", name, count, v->len / 8);
        return NULL;
    }
    return v->buf;
}

static int csr_valid(const int64_t *p, const int64_t *idx, Py_ssize_t A, Py_ssize_t S, Py_ssize_t ncol,
                     Py_ssize_t nnz, const char *name)
{
    for (Py_ssize_t a = 0; a < A; a++) {
        const int64_t *row = p + a * (S + 1);
        for (Py_ssize_t s = 0; s < S; s++)
            if (row[s] < 0 || row[s] > row[s + 1] || row[s + 1] > nnz) {
                PyErr_Format(PyExc_ValueError, "%s: indptr of action %zd is not non-decreasing within 0..%zd",
                             name, a, nnz);
                return 0;
            }
    }
    for (Py_ssize_t j = 0; j < nnz; j++)
        if (idx[j] < 0 || idx[j] >= ncol) {
            PyErr_Format(PyExc_ValueError, "%s: column index %lld out of range 0..%zd", name,
                         (long long)idx[j], ncol - 1);
            return 0;
        }
    return 1;
}

static Py_ssize_t buffer_items(PyObject *obj)
{
    Py_buffer v;
    if (PyObject_GetBuffer(obj, &v, PyBUF_SIMPLE) < 0)
        return -1;
    Py_ssize_t n = v.len / 8;
    PyBuffer_Release(&v);
    return n;
}

/* CSR rows per action (a tuple indptr, indices, data; module comment of tables_new) of a matrix
 * with ``ncol`` columns and S rows per action, into the views; returns the non-zeros or -1. */
static Py_ssize_t take_csr(Tables *self, PyObject *csr, Py_ssize_t ncol, const char *name, const int64_t **indptr,
                           const int64_t **indices, const double **data)
{
    PyObject *p, *i, *x;
    if (!PyArg_ParseTuple(csr, "OOO", &p, &i, &x))
        return -1;
    Py_ssize_t A = self->A, S = self->S, nnz = buffer_items(i);
    if (nnz < 0 || !(*indptr = take_view(self, p, "q", A * (S + 1), name))
        || !(*indices = take_view(self, i, "q", nnz, name)) || !(*data = take_view(self, x, "d", nnz, name))
        || !csr_valid(*indptr, *indices, A, S, ncol, nnz, name))
        return -1;
    return nnz;
}

/*
 * Tables(S, A, Z, gamma, kind, w, r, rT, Cg, Ch, P, O, OT, X, W, MT)
 *
 * P: a float64 buffer (dense, A*S*S) or a tuple (indptr, indices, data) of CSR rows per action
 * (indptr int64 of A*(S+1) absolute offsets). O: dense (A*S*Z) or CSR (rows: states, columns:
 * observations). OT: dense O transposed (A*Z*S), None with CSR O. X: O^2 / O log O in O's layout
 * (a buffer of A*S*Z for dense O, the values on O's pattern for CSR O), None for kind none.
 * Cg, Ch: None (no bounds) or A*S each. W: None or the fused leaf table of dense O (A*S*Kw,
 * Kw = nblk Zp: blocks O, O r_0, ..., O r_{A-1}, then X (Renyi, Shannon) and O (Shannon), each
 * of Z columns zero-padded to Zp, Z rounded up to a multiple of PAD: leaf_products). MT: S*NM,
 * NM = 3A (with bounds) or A rounded up to a multiple of PAD, zero-padded:
 * S*A: [r | Cg^T | Ch^T].
 */
static PyObject *tables_new(PyTypeObject *type, PyObject *args, PyObject *kwds)
{
    Py_ssize_t S, A, Z;
    double gamma;
    int kind;
    PyObject *w, *r, *rT, *Cg, *Ch, *P, *O, *OT, *X, *W, *MT;
    if (kwds && PyDict_Size(kwds)) {
        PyErr_SetString(PyExc_TypeError, "Tables takes positional arguments only");
        return NULL;
    }
    if (!PyArg_ParseTuple(args, "nnndiOOOOOOOOOOO", &S, &A, &Z, &gamma, &kind, &w, &r, &rT, &Cg, &Ch, &P, &O,
                          &OT, &X, &W, &MT))
        return NULL;
    if (S < 1 || A < 1 || Z < 1 || kind < KIND_NONE || kind > KIND_SHANNON) {
        PyErr_SetString(PyExc_ValueError, "Tables: bad sizes or kind");
        return NULL;
    }
    Tables *self = (Tables *)type->tp_alloc(type, 0);
    if (!self)
        return NULL;
    self->S = S; self->A = A; self->Z = Z; self->gamma = gamma; self->kind = kind;
    if (!(self->w = take_view(self, w, "d", A, "w")) || !(self->r = take_view(self, r, "d", S * A, "r"))
        || !(self->rT = take_view(self, rT, "d", A * S, "rT")))
        goto fail;
    if ((Cg == Py_None) != (Ch == Py_None)) {
        PyErr_SetString(PyExc_ValueError, "Cg, Ch: both or neither");
        goto fail;
    }
    if (Cg != Py_None && (!(self->Cg = take_view(self, Cg, "d", A * S, "Cg"))
                          || !(self->Ch = take_view(self, Ch, "d", A * S, "Ch"))))
        goto fail;
    if (PyTuple_Check(P)) {
        if (take_csr(self, P, S, "P", &self->Pp, &self->Pi, &self->Px) < 0)
            goto fail;
        self->p_sparse = 1;
    } else if (!(self->P = take_view(self, P, "d", A * S * S, "P"))) {
        goto fail;
    }
    if (PyTuple_Check(O)) {
        Py_ssize_t nnz = take_csr(self, O, Z, "O", &self->Op, &self->Oi, &self->Ox);
        if (nnz < 0)
            goto fail;
        if (kind != KIND_NONE && !(self->Xx = take_view(self, X, "d", nnz, "X")))
            goto fail;
        self->o_sparse = 1;
    } else {
        if (!(self->O = take_view(self, O, "d", A * S * Z, "O")) || !(self->OT = take_view(self, OT, "d", A * Z * S, "OT")))
            goto fail;
        if (kind != KIND_NONE && !(self->X = take_view(self, X, "d", A * S * Z, "X")))
            goto fail;
        self->Zp = (Z + PAD - 1) / PAD * PAD;
        self->nblk = A + 1 + (kind != KIND_NONE) + (kind == KIND_SHANNON);
        self->Kw = self->nblk * self->Zp;
        if (W != Py_None && !(self->W = take_view(self, W, "d", A * S * self->Kw, "W")))
            goto fail;
    }
    self->NM = ((self->Cg ? 3 * A : A) + PAD - 1) / PAD * PAD;
    if (!(self->MT = take_view(self, MT, "d", S * self->NM, "MT")))
        goto fail;
    return (PyObject *)self;
fail:
    Py_DECREF(self);
    return NULL;
}

static PyTypeObject TablesType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "_pomdp_planner_kernel.Tables",
    .tp_doc = "A model's tables for the search kernel (core/search_kernel.py builds them).",
    .tp_basicsize = sizeof(Tables),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = tables_new,
    .tp_dealloc = (destructor)tables_dealloc,
};

/* ------------------------------------------------------------------------------ logarithm */

/*
 * Natural logarithm of a positive finite double (subnormals included), written so that a loop
 * over an array of them vectorises: fdlibm's e_log.c reduction (x = 2^k m, m in [sqrt(2)/2,
 * sqrt(2)), f = m - 1, s = f / (2 + f)) and its degree-14 odd polynomial, error below 1 ulp.
 * The leaves' logarithms go through it in blocks (one per step's parent and action).
 */
static const double Lg1 = 6.666666666666735130e-01, Lg2 = 3.999999999940941908e-01,
                    Lg3 = 2.857142874366239149e-01, Lg4 = 2.222219843214978396e-01,
                    Lg5 = 1.818357216161805012e-01, Lg6 = 1.531383769920937332e-01,
                    Lg7 = 1.479819860511658591e-01;
static const double ln2_hi = 6.93147180369123816490e-01, ln2_lo = 1.90821492927058770002e-10;

INLINE double klog(double x)
{
    int sub = x < 2.2250738585072014e-308;
    double xs = sub ? x * 18014398509481984.0 : x; /* 2^54 */
    uint64_t ix;
    memcpy(&ix, &xs, 8);
    uint64_t eb = (ix >> 52) | 0x4330000000000000ULL;
    double e;
    memcpy(&e, &eb, 8);
    e -= 4503599627370496.0 + 1023.0; /* 2^52: the biased exponent as a double, unbiased */
    e = sub ? e - 54.0 : e;
    uint64_t im = (ix & 0x000fffffffffffffULL) | 0x3ff0000000000000ULL;
    double m;
    memcpy(&m, &im, 8); /* in [1, 2) */
    int big = m > 1.4142135623730951;
    m = big ? 0.5 * m : m;
    e = big ? e + 1.0 : e;
    double f = m - 1.0;
    double s = f / (2.0 + f);
    double z = s * s, w = z * z;
    double t1 = w * (Lg2 + w * (Lg4 + w * Lg6));
    double t2 = z * (Lg1 + w * (Lg3 + w * (Lg5 + w * Lg7)));
    double R = t2 + t1;
    double hfsq = 0.5 * f * f;
    return e * ln2_hi - ((hfsq - (s * (hfsq + R) + e * ln2_lo)) - f);
}

/* ------------------------------------------------------------------------- a search's state */

typedef struct {
    Py_ssize_t cap;   /* nodes the level can hold */
    double *B;        /* cap x S beliefs */
    double *rho;      /* cap x A */
    double *Q;        /* cap x A */
    double *eta;      /* cap: the branch probability of each node (levels >= 1) */
    double *V;        /* cap */
    Py_ssize_t *par;  /* cap: index of the node's parent in the level above */
    int *lo, *up;     /* cap: the allowed actions [lo, up] (every action if crossed or no bounds) */
} Level;

typedef struct {
    const Tables *t;
    const double *cost;    /* A */
    int use_bounds;        /* below the root (and the root's bounds, when not all_root) */
    int count_only;        /* count the tree (leaves: eta only), value nothing */
    Py_ssize_t leaf_chunk, expand_chunk;
    const Py_ssize_t *order0; /* the root level's action order */
    Py_ssize_t *order;        /* 0..A-1 */
    int64_t *sizes;        /* depth + 1 */
    /* deadline */
    int has_deadline, first_free, steps0;
    double deadline;
    PyObject *clock;       /* NULL: the native monotonic clock */
    PyThreadState *save;   /* the released GIL (NULL while held) */
    Level *lev;
    double *scratch;       /* per-step work arrays */
    double *block;         /* a leaf step's block arrays (leaf_scratch) */
    double *acc;           /* per-parent sums of a step (expand chunk) */
} Search;

static double monotonic_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* DONE: go on; INTERRUPTED: the deadline has passed; FAILED: the clock raised (error set). */
static int check_deadline(Search *c, int level)
{
    if (!c->has_deadline)
        return DONE;
    if (level == 0 && c->first_free && c->steps0++ == 0)
        return DONE;
    double now;
    if (c->clock == NULL) {
        now = monotonic_now();
    } else {
        PyEval_RestoreThread(c->save);
        c->save = NULL;
        PyObject *v = PyObject_CallNoArgs(c->clock);
        now = v ? PyFloat_AsDouble(v) : -1.0;
        Py_XDECREF(v);
        int err = PyErr_Occurred() != NULL;
        c->save = PyEval_SaveThread();
        if (err)
            return FAILED;
    }
    return now > c->deadline ? INTERRUPTED : DONE;
}

/* ----------------------------------------------------------------- prediction, observation */

/*
 * y[0..m) = sum_i x[i] M[i ld + 0..m): a vector times the rows of a matrix, in tiles of TILE
 * columns whose sums stay in registers (GCC and clang vector types; elsewhere plain loops), the
 * sums over i in order.
 */
#if defined(__GNUC__)
typedef double v4d __attribute__((vector_size(32)));

/* An unaligned load of 4 doubles (a statement expression: no vector crosses a call). */
#define load4(p) __extension__({ v4d v_; memcpy(&v_, (p), sizeof(v_)); v_; })

INLINE void gemv_rows(const double *restrict x, Py_ssize_t n, const double *restrict M, Py_ssize_t ld,
                      Py_ssize_t m, double *restrict y)
{
    Py_ssize_t q = 0;
    for (; q + TILE <= m; q += TILE) {
        v4d a0 = {0.0, 0.0, 0.0, 0.0}, a1 = a0;
        const double *r = M + q;
        for (Py_ssize_t i = 0; i < n; i++, r += ld) {
            v4d xi = {x[i], x[i], x[i], x[i]};
            a0 += xi * load4(r);
            a1 += xi * load4(r + 4);
        }
        memcpy(y + q, &a0, sizeof(a0));
        memcpy(y + q + 4, &a1, sizeof(a1));
    }
    for (; q + 4 <= m; q += 4) {
        v4d a0 = {0.0, 0.0, 0.0, 0.0};
        const double *r = M + q;
        for (Py_ssize_t i = 0; i < n; i++, r += ld) {
            v4d xi = {x[i], x[i], x[i], x[i]};
            a0 += xi * load4(r);
        }
        memcpy(y + q, &a0, sizeof(a0));
    }
    for (; q < m; q++) {
        double acc = 0.0;
        for (Py_ssize_t i = 0; i < n; i++)
            acc += x[i] * M[i * ld + q];
        y[q] = acc;
    }
}
#else
INLINE void gemv_rows(const double *restrict x, Py_ssize_t n, const double *restrict M, Py_ssize_t ld,
                      Py_ssize_t m, double *restrict y)
{
    for (Py_ssize_t q = 0; q < m; q++) {
        double acc = 0.0;
        for (Py_ssize_t i = 0; i < n; i++)
            acc += x[i] * M[i * ld + q];
        y[q] = acc;
    }
}
#endif

/* ba = b P[a] (Eq. 1). */
INLINE void predict(const Tables *t, const double *b, Py_ssize_t a, double *restrict ba)
{
    Py_ssize_t S = t->S;
    if (!t->p_sparse) {
        gemv_rows(b, S, t->P + a * S * S, S, S, ba);
    } else {
        memset(ba, 0, S * sizeof(double));
        const int64_t *p = t->Pp + a * (S + 1);
        for (Py_ssize_t i = 0; i < S; i++) {
            double bi = b[i];
            if (bi == 0.0)
                continue;
            for (int64_t k = p[i]; k < p[i + 1]; k++)
                ba[t->Pi[k]] += bi * t->Px[k];
        }
    }
}

/*
 * The observation sums of the predicted belief ba under action a, per observation z:
 * eta[z] = sum_s u_s; if lin: lin[a' Z + z] = sum_s u_s r[s, a'] for every a'; if sq: the
 * uncertainty sum (Renyi: sum_s u_s^2; Shannon: sum_s u_s log u_s); u_s = ba_s O[a][s, z].
 */
INLINE void observe(const Tables *t, const double *restrict ba, Py_ssize_t a, double *restrict eta,
                           double *restrict lin, double *restrict sq)
{
    Py_ssize_t S = t->S, A = t->A, Z = t->Z;
    memset(eta, 0, Z * sizeof(double));
    if (lin)
        memset(lin, 0, A * Z * sizeof(double));
    if (sq)
        memset(sq, 0, Z * sizeof(double));
    int kind = t->kind;
    if (!t->o_sparse && !lin) {
        gemv_rows(ba, S, t->O + a * S * Z, Z, Z, eta);
        return;
    }
    if (!t->o_sparse) {
        const double *O = t->O + a * S * Z, *X = t->X ? t->X + a * S * Z : NULL;
        for (Py_ssize_t s = 0; s < S; s++) {
            double c = ba[s];
            if (c == 0.0)
                continue;
            const double *o = O + s * Z;
            for (Py_ssize_t z = 0; z < Z; z++)
                eta[z] += c * o[z];
            if (!lin)
                continue;
            const double *rs = t->r + s * A;
            for (Py_ssize_t k = 0; k < A; k++) {
                double cr = c * rs[k];
                double *l = lin + k * Z;
                for (Py_ssize_t z = 0; z < Z; z++)
                    l[z] += cr * o[z];
            }
            if (!sq)
                continue;
            const double *x = X + s * Z;
            if (kind == KIND_RENYI2) {
                double c2 = c * c;
                for (Py_ssize_t z = 0; z < Z; z++)
                    sq[z] += c2 * x[z];
            } else {
                double cl = c * log(c);
                for (Py_ssize_t z = 0; z < Z; z++)
                    sq[z] += cl * o[z] + c * x[z];
            }
        }
    } else {
        const int64_t *p = t->Op + a * (S + 1);
        for (Py_ssize_t s = 0; s < S; s++) {
            double c = ba[s];
            if (c == 0.0)
                continue;
            const double *rs = t->r + s * A;
            /* Renyi: u^2 = c^2 O^2; Shannon: u log u = c log c O + c O log O */
            double cx = kind == KIND_RENYI2 ? c * c : c;
            double cl = sq && kind == KIND_SHANNON ? c * log(c) : 0.0;
            for (int64_t k = p[s]; k < p[s + 1]; k++) {
                Py_ssize_t z = t->Oi[k];
                double o = t->Ox[k], u = c * o;
                eta[z] += u;
                if (!lin)
                    continue;
                for (Py_ssize_t q = 0; q < A; q++)
                    lin[q * Z + z] += (c * rs[q]) * o;
                if (sq)
                    sq[z] += cl * o + cx * t->Xx[k];
            }
        }
    }
}

/* The posterior tau(b, a, z) = ba o O[a][:, z] / eta (Eq. 2) into out. */
INLINE void posterior(const Tables *t, const double *restrict ba, Py_ssize_t a, Py_ssize_t z, double eta,
                             double *restrict out)
{
    Py_ssize_t S = t->S;
    if (!t->o_sparse) {
        const double *ot = t->OT + (a * t->Z + z) * S;
        double inv = 1.0 / eta;
        for (Py_ssize_t s = 0; s < S; s++)
            out[s] = ba[s] * ot[s] * inv;
    } else {
        const int64_t *p = t->Op + a * (S + 1);
        for (Py_ssize_t s = 0; s < S; s++) {
            double v = 0.0;
            if (ba[s] != 0.0)
                for (int64_t k = p[s]; k < p[s + 1]; k++)
                    if (t->Oi[k] == z) {
                        v = ba[s] * t->Ox[k] / eta;
                        break;
                    }
            out[s] = v;
        }
    }
}

/* ------------------------------------------------------------------ rewards and bounds */

INLINE double uncertainty(const Tables *t, const double *b)
{
    Py_ssize_t S = t->S;
    double f = 0.0;
    if (t->kind == KIND_RENYI2) {
        for (Py_ssize_t s = 0; s < S; s++)
            f += b[s] * b[s];
        return -klog(f);
    }
    if (t->kind == KIND_SHANNON) {
        for (Py_ssize_t s = 0; s < S; s++) {
            double x = b[s] > 0.0 ? b[s] : 1.0;
            f -= b[s] * klog(x);
        }
        return f;
    }
    return 0.0;
}

/* The smallest index whose value is within TIE_RTOL (relative) of the maximum (core/myopic.py:
 * argmax_smallest); with ``last``, the largest such index. */
INLINE int tie_argmax(const double *v, Py_ssize_t n, int last)
{
    double top = v[0];
    for (Py_ssize_t i = 1; i < n; i++)
        top = v[i] > top ? v[i] : top;
    double tol = TIE_RTOL * (fabs(top) > 1.0 ? fabs(top) : 1.0);
    if (!last) {
        for (Py_ssize_t i = 0; i < n; i++)
            if (v[i] >= top - tol)
                return (int)i;
    } else {
        for (Py_ssize_t i = n - 1; i >= 0; i--)
            if (v[i] >= top - tol)
                return (int)i;
    }
    return 0;
}

/*
 * rho(b, .) (Eq. 3) into rho[A]; with bounds, the myopic bound actions (Eq. 8) into *lo, *up
 * (raw: crossed bounds stay crossed here), else [0, A-1]. One product b^T MT gives r^T b and the
 * bound terms C_g b, C_h b. work: 3A doubles.
 */
INLINE void node_info(const Search *c, const double *restrict b, double *restrict rho, int *lo, int *up,
                             double *restrict work)
{
    const Tables *t = c->t;
    Py_ssize_t S = t->S, A = t->A, NM = t->NM;
    int bounded = c->use_bounds && t->Cg != NULL;
    Py_ssize_t nm = bounded ? NM : (A + PAD - 1) / PAD * PAD;
    double f = t->kind == KIND_NONE ? 0.0 : uncertainty(t, b);
    gemv_rows(b, S, t->MT, NM, nm, work);
    for (Py_ssize_t a = 0; a < A; a++)
        rho[a] = work[a] - c->cost[a] - t->w[a] * f;
    if (!bounded) {
        *lo = 0;
        *up = (int)A - 1;
        return;
    }
    double *T0 = work + A, *T1 = work + 2 * A;
    for (Py_ssize_t a = 0; a < A; a++) {
        T0[a] += rho[a];
        T1[a] += rho[a];
    }
    *lo = tie_argmax(T0, A, 0);
    *up = tie_argmax(T1, A, 1);
}

/* ------------------------------------------------------------------------------- leaves */

/* Whether node p of level L allows action a (crossed bounds allow every action). */
INLINE int allows(const Level *L, Py_ssize_t p, Py_ssize_t a)
{
    int lo = L->lo[p], up = L->up[p];
    return lo > up || (lo <= a && a <= up);
}


/* Parents whose leaves are valued together (their logarithms in one loop). */
#define LEAF_BLOCK 32

/* Columns of one parent's observation sums (leaf_products): the fused table's, or (A + 2) Z. */
static inline Py_ssize_t leaf_y(const Tables *t)
{
    return t->W != NULL ? t->Kw : (t->A + 2) * t->Z;
}

/*
 * The observation sums of one predicted belief ba under action a into y, in blocks of ``ys``
 * columns (file comment): y[z] = eta_z, y[(1 + a') ys + z] = u . r_a', and, valuing (not
 * counting), y[(A + 1) ys + z] = sum_s u_s^2 (Renyi) or sum_s u_s log u_s (Shannon; with the fused
 * table in two blocks, (A + 1) and (A + 2), to be added). With the fused table W[a] (rows s:
 * [O | O r_0 | ... | O r_{A-1} | X (| O)], blocks padded to Zp) one matrix-vector product per
 * block, with the coefficients ba_s, then ba_s^2 (Renyi X = O^2) or ba_s (Shannon X = O log O) and
 * ba_s log ba_s (Shannon's second O); without it (large models, CSR O) observe() above. Returns
 * ys. work: 2 S doubles.
 */
INLINE Py_ssize_t leaf_products(const Tables *t, const double *restrict ba, Py_ssize_t a, double *restrict y,
                                int count_only, double *restrict work)
{
    Py_ssize_t S = t->S, A = t->A, Z = t->Z;
    int kind = t->kind;
    if (t->W == NULL || count_only) {
        observe(t, ba, a, y, count_only ? NULL : y + Z, count_only || kind == KIND_NONE ? NULL : y + (A + 1) * Z);
        return Z;
    }
    Py_ssize_t Zp = t->Zp, Kw = t->Kw;
    const double *W = t->W + a * S * Kw;
    for (Py_ssize_t k = 0; k <= A; k++)
        gemv_rows(ba, S, W + k * Zp, Kw, Zp, y + k * Zp);
    if (kind == KIND_NONE)
        return Zp;
    double *cx = work, *cl = work + S;
    if (kind == KIND_RENYI2) {
        for (Py_ssize_t s = 0; s < S; s++)
            cx[s] = ba[s] * ba[s];
        gemv_rows(cx, S, W + (A + 1) * Zp, Kw, Zp, y + (A + 1) * Zp);
    } else {
        for (Py_ssize_t s = 0; s < S; s++)
            cl[s] = ba[s] * klog(ba[s] > 0.0 ? ba[s] : 1.0);
        gemv_rows(ba, S, W + (A + 1) * Zp, Kw, Zp, y + (A + 1) * Zp);
        gemv_rows(cl, S, W + (A + 2) * Zp, Kw, Zp, y + (A + 2) * Zp);
    }
    return Zp;
}

/*
 * One leaf step: Q[p][a] = rho[p][a] + gamma sum_z eta_z V(tau(b_p, a, z)) for the parents
 * p in [s0, s1) of level L that allow a, V(leaf) = max_a' rho(leaf, a') by the fused formulas
 * (file comment); returns the number of leaves (possible branches). Counting: only that.
 */
HOT static int64_t leaf_step(Search *c, Level *L, Py_ssize_t s0, Py_ssize_t s1, Py_ssize_t a)
{
    const Tables *t = c->t;
    Py_ssize_t S = t->S, A = t->A, Z = t->Z, Ky = leaf_y(t);
    int kind = t->kind;
    double gamma = t->gamma;
    const double *cost = c->cost, *w = t->w;
    double *BA = c->block, *Y = BA + LEAF_BLOCK * S, *E = Y + LEAF_BLOCK * Ky, *LG = E + LEAF_BLOCK * Z;
    double *M = LG + LEAF_BLOCK * Z, *TZ = M + Z, *tau = TZ + Z, *work = tau + S;
    Py_ssize_t idx[LEAF_BLOCK];
    int64_t leaves = 0;
    Py_ssize_t p = s0, ys = Z;
    for (;;) {
        Py_ssize_t nb = 0;
        for (; p < s1 && nb < LEAF_BLOCK; p++)
            if (allows(L, p, a))
                idx[nb++] = p;
        if (nb == 0)
            break;
        for (Py_ssize_t j = 0; j < nb; j++) {
            double *ba = BA + j * S, *y = Y + j * Ky;
            predict(t, L->B + idx[j] * S, a, ba);
            ys = leaf_products(t, ba, a, y, c->count_only, work);
            memcpy(E + j * Z, y, Z * sizeof(double));
        }
        if (c->count_only) {
            for (Py_ssize_t i = 0; i < nb * Z; i++)
                leaves += E[i] > ETA_SKIP;
            continue;
        }
        Py_ssize_t xo = (A + 1) * ys; /* the uncertainty sums; Shannon's fused second block at xo + ys */
        int two = kind == KIND_SHANNON && t->W != NULL;
        /* the block's logarithms in one vectorised loop (a dummy 1 where eta is too small) */
        if (kind == KIND_RENYI2) {
            for (Py_ssize_t j = 0; j < nb; j++) {
                const double *sq = Y + j * Ky + xo, *e = E + j * Z;
                double *lg = LG + j * Z;
                for (Py_ssize_t z = 0; z < Z; z++)
                    lg[z] = e[z] >= ETA_FUSED_MIN ? sq[z] / (e[z] * e[z]) : 1.0;
            }
        } else if (kind == KIND_SHANNON) {
            for (Py_ssize_t i = 0; i < nb * Z; i++)
                LG[i] = E[i] >= ETA_FUSED_MIN ? E[i] : 1.0;
        }
        if (kind != KIND_NONE)
            for (Py_ssize_t i = 0; i < nb * Z; i++)
                LG[i] = klog(LG[i]);
        for (Py_ssize_t j = 0; j < nb; j++) {
            const double *y = Y + j * Ky, *e = E + j * Z, *lg = LG + j * Z;
            /* TZ = -eta f(tau) */
            if (kind == KIND_RENYI2)
                for (Py_ssize_t z = 0; z < Z; z++)
                    TZ[z] = e[z] * lg[z];
            else if (kind == KIND_SHANNON)
                for (Py_ssize_t z = 0; z < Z; z++)
                    TZ[z] = y[xo + z] + (two ? y[xo + ys + z] : 0.0) - e[z] * lg[z];
            else
                for (Py_ssize_t z = 0; z < Z; z++)
                    TZ[z] = 0.0;
            for (Py_ssize_t z = 0; z < Z; z++)
                M[z] = y[ys + z] - cost[0] * e[z] + w[0] * TZ[z];
            for (Py_ssize_t k = 1; k < A; k++) {
                const double *lin = y + (k + 1) * ys;
                double ck = cost[k], wk = w[k];
                for (Py_ssize_t z = 0; z < Z; z++) {
                    double v = lin[z] - ck * e[z] + wk * TZ[z];
                    M[z] = v > M[z] ? v : M[z];
                }
            }
            double total = 0.0;
            int tiny = 0;
            for (Py_ssize_t z = 0; z < Z; z++) {
                double ez = e[z];
                if (!(ez > ETA_SKIP))
                    continue;
                leaves++;
                if (kind != KIND_NONE && ez < ETA_FUSED_MIN)
                    tiny = 1;
                else
                    total += M[z];
            }
            if (tiny) { /* eta V from the normalised posterior, where u_s^2 could underflow */
                const double *ba = BA + j * S;
                for (Py_ssize_t z = 0; z < Z; z++) {
                    double ez = e[z];
                    if (!(ez > ETA_SKIP) || ez >= ETA_FUSED_MIN)
                        continue;
                    posterior(t, ba, a, z, ez, tau);
                    double f = uncertainty(t, tau), m = 0.0;
                    for (Py_ssize_t k = 0; k < A; k++) {
                        const double *rk = t->rT + k * S;
                        double v = 0.0;
                        for (Py_ssize_t s = 0; s < S; s++)
                            v += rk[s] * tau[s];
                        v = v - cost[k] - w[k] * f;
                        m = (k == 0 || v > m) ? v : m;
                    }
                    total += ez * m;
                }
            }
            Py_ssize_t q = idx[j] * A + a;
            L->Q[q] = L->rho[q] + gamma * total;
        }
    }
    return leaves;
}

/* Scratch doubles of a leaf step (leaf_step's layout). */
static size_t leaf_scratch(const Tables *t)
{
    size_t S = t->S, Z = t->Z;
    return LEAF_BLOCK * (S + leaf_y(t) + 2 * Z) + 2 * Z + 3 * S;
}

/* --------------------------------------------------------------------------- the search */

/*
 * One expansion step: the children of the parents p in [s0, s1) of level L that allow a, into
 * level C (parent-major, then observation; impossible branches skipped), with their rho and
 * bounds. Returns the number of children.
 */
HOT static Py_ssize_t expand_step(Search *c, Level *L, Level *C, Py_ssize_t s0, Py_ssize_t s1, Py_ssize_t a)
{
    const Tables *t = c->t;
    Py_ssize_t S = t->S, A = t->A, Z = t->Z;
    double *ba = c->scratch, *eta = ba + S, *work = eta + Z;
    Py_ssize_t k = 0;
    for (Py_ssize_t p = s0; p < s1; p++) {
        if (!allows(L, p, a))
            continue;
        predict(t, L->B + p * S, a, ba);
        observe(t, ba, a, eta, NULL, NULL);
        for (Py_ssize_t z = 0; z < Z; z++) {
            if (!(eta[z] > ETA_SKIP))
                continue;
            double *child = C->B + k * S;
            posterior(t, ba, a, z, eta[z], child);
            node_info(c, child, C->rho + k * A, &C->lo[k], &C->up[k], work);
            C->eta[k] = eta[z];
            C->par[k] = p;
            k++;
        }
    }
    return k;
}

/*
 * Q of the nodes 0..n-1 of level ``d`` (rem >= 1 levels below them) into lev[d].Q (-inf where
 * not allowed or not reached), and, for d >= 1, V = max_a Q into lev[d].V. The traversal of the
 * file comment.
 */
static int level_values(Search *c, int d, Py_ssize_t n, int rem)
{
    const Tables *t = c->t;
    Py_ssize_t A = t->A;
    Level *L = &c->lev[d];
    const Py_ssize_t *order = d == 0 ? c->order0 : c->order;
    Py_ssize_t step = rem == 1 ? c->leaf_chunk : c->expand_chunk;
    double gamma = t->gamma;
    for (Py_ssize_t i = 0; i < n * A; i++)
        L->Q[i] = -INFINITY;
    for (Py_ssize_t s0 = 0; s0 < n; s0 += step) {
        Py_ssize_t s1 = s0 + step < n ? s0 + step : n;
        for (Py_ssize_t oi = 0; oi < A; oi++) {
            Py_ssize_t a = order[oi];
            Py_ssize_t p;
            for (p = s0; p < s1 && !allows(L, p, a); p++)
                ;
            if (p == s1)
                continue;
            int st = check_deadline(c, d);
            if (st != DONE)
                return st;
            if (rem == 1) {
                c->sizes[d + 1] += leaf_step(c, L, s0, s1, a);
                continue;
            }
            /* the children of this step, then their values (depth-first) */
            Level *C = &c->lev[d + 1];
            Py_ssize_t k = expand_step(c, L, C, s0, s1, a);
            c->sizes[d + 1] += k;
            st = level_values(c, d + 1, k, rem - 1);
            if (st != DONE)
                return st;
            if (c->count_only)
                continue;
            double *acc = c->acc;
            for (p = s0; p < s1; p++)
                acc[p - s0] = 0.0;
            for (Py_ssize_t j = 0; j < k; j++)
                acc[C->par[j] - s0] += C->eta[j] * C->V[j];
            for (p = s0; p < s1; p++)
                if (allows(L, p, a))
                    L->Q[p * A + a] = L->rho[p * A + a] + gamma * acc[p - s0];
        }
    }
    if (d > 0 && !c->count_only)
        for (Py_ssize_t p = 0; p < n; p++) {
            const double *q = L->Q + p * A;
            double m = q[0];
            for (Py_ssize_t a = 1; a < A; a++)
                m = q[a] > m ? q[a] : m;
            L->V[p] = m;
        }
    return DONE;
}

/* A writable (or read-only) C-contiguous buffer of exactly ``count`` 8-byte items. */
static int get_buffer(PyObject *obj, Py_buffer *v, Py_ssize_t count, int writable, const char *name)
{
    if (PyObject_GetBuffer(obj, v, PyBUF_C_CONTIGUOUS | (writable ? PyBUF_WRITABLE : 0)) < 0)
        return 0;
    if (v->len != count * 8) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd items of 8 bytes, got %zd bytes", name, count, v->len);
        PyBuffer_Release(v);
        return 0;
    }
    return 1;
}

typedef struct {
    double rho;
    Py_ssize_t a;
} Ranked;

static int by_rho(const void *x, const void *y)
{
    const Ranked *p = x, *q = y;
    if (p->rho != q->rho)
        return p->rho > q->rho ? -1 : 1;
    return p->a < q->a ? -1 : (p->a > q->a);
}

/*
 * The belief rule of core/belief.py (check_belief) on the n rows of B: every entry finite and
 * >= -atol, the sum within atol of 1. Returns the first row that breaks it (B untouched), or -1
 * after clipping every row at 0 and dividing it by its clipped sum, in place.
 */
static Py_ssize_t check_rows(double *B, Py_ssize_t n, Py_ssize_t S, double atol)
{
    for (Py_ssize_t i = 0; i < n; i++) {
        const double *b = B + i * S;
        double total = 0.0, clipped = 0.0;
        for (Py_ssize_t s = 0; s < S; s++) {
            double x = b[s];
            if (!isfinite(x) || x < -atol)
                return i;
            total += x;
            clipped += x > 0.0 ? x : 0.0;
        }
        if (fabs(total - 1.0) > atol || !(clipped > 0.0))
            return i;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        double *b = B + i * S, clipped = 0.0;
        for (Py_ssize_t s = 0; s < S; s++) {
            b[s] = b[s] > 0.0 ? b[s] : 0.0;
            clipped += b[s];
        }
        for (Py_ssize_t s = 0; s < S; s++)
            b[s] /= clipped;
    }
    return -1;
}

/*
 * search(tables, B, n, depth, use_bounds, all_root, rho_order, cost, leaf_chunk, expand_chunk,
 *        deadline, clock, first_free, count_only, atol, Q) -> (status, index, sizes, lower, upper)
 *
 * B: n roots (n x S float64). depth >= 0 action-observation levels (0: Q = rho at the roots).
 * use_bounds: the myopic bounds at every node (else every action); all_root: every root action
 * all the same. rho_order: the root actions in decreasing rho (ties: smaller index first; n must
 * be 1), else 0..A-1. cost: None or A float64 (the price). deadline: None or a reading of
 * ``clock`` (None: the native monotonic clock, time.perf_counter's on Linux); first_free: the
 * root level's first step is not checked. count_only: count the tree, value nothing. atol: None
 * (the roots are beliefs already checked) or the tolerance of the belief rule (check_rows; B must
 * then be writable: the roots are normalised in place).
 * Q: None (counting) or a writable n x A float64 buffer: the roots' Q values, NaN where not
 * searched. Returns status 0 (done), 1 (the deadline passed: Q holds what was finished) or 2 (root
 * ``index`` breaks the belief rule: nothing was searched); index: with 0 or 1 the first root's
 * best searched action (smallest on ties; -1 if none); sizes: nodes per level (a tuple);
 * lower, upper: the first root's raw bound actions (-1 without bounds).
 */
static PyObject *kernel_search(PyObject *module, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 16) {
        PyErr_SetString(PyExc_TypeError, "search: 16 arguments expected");
        return NULL;
    }
    if (!PyObject_TypeCheck(args[0], &TablesType)) {
        PyErr_SetString(PyExc_TypeError, "search: tables must be a Tables object");
        return NULL;
    }
    Tables *t = (Tables *)args[0];
    Py_ssize_t S = t->S, A = t->A, Z = t->Z;
    Py_ssize_t n = PyLong_AsSsize_t(args[2]);
    long depth = PyLong_AsLong(args[3]);
    int use_bounds = PyObject_IsTrue(args[4]), all_root = PyObject_IsTrue(args[5]);
    int rho_order = PyObject_IsTrue(args[6]);
    Py_ssize_t leaf_chunk = PyLong_AsSsize_t(args[8]), expand_chunk = PyLong_AsSsize_t(args[9]);
    int first_free = PyObject_IsTrue(args[12]), count_only = PyObject_IsTrue(args[13]);
    double atol = args[14] == Py_None ? -1.0 : PyFloat_AsDouble(args[14]);
    if (PyErr_Occurred())
        return NULL;
    if (n < 1 || depth < 0 || depth > 1000 || leaf_chunk < 1 || expand_chunk < 1 || (rho_order && n != 1)
        || (args[15] == Py_None && !count_only)) {
        PyErr_SetString(PyExc_ValueError, "search: bad n, depth, chunk sizes, order or output");
        return NULL;
    }
    PyObject *result = NULL;
    Search c;
    memset(&c, 0, sizeof(c));
    c.t = t;
    c.use_bounds = use_bounds;
    c.count_only = count_only;
    c.leaf_chunk = leaf_chunk;
    c.expand_chunk = expand_chunk;
    c.first_free = first_free;
    if (args[10] != Py_None) {
        c.has_deadline = 1;
        c.deadline = PyFloat_AsDouble(args[10]);
        if (PyErr_Occurred())
            return NULL;
        c.clock = args[11] == Py_None ? NULL : args[11];
    }
    Py_buffer vB, vcost, vQ;
    int have_cost = args[7] != Py_None, have_Q = args[15] != Py_None;
    if (!get_buffer(args[1], &vB, n * S, atol >= 0.0, "B"))
        return NULL;
    if (have_cost && !get_buffer(args[7], &vcost, A, 0, "cost"))
        goto release_B;
    if (have_Q && !get_buffer(args[15], &vQ, n * A, 1, "Q"))
        goto release_cost;

    /* level capacities: level d + 1 holds the children of one step of level d */
    Py_ssize_t caps[1002];
    caps[0] = n;
    size_t doubles = 0, ints = 0, idx = 0;
    Py_ssize_t widest = 1; /* the most parents of one expansion step (acc) */
    for (long d = 0; d < depth; d++) {
        if (d >= 1) {
            doubles += (size_t)caps[d] * (S + 2 * A + 2);
            ints += 2 * (size_t)caps[d];
            idx += (size_t)caps[d];
        }
        Py_ssize_t step = depth - d == 1 ? leaf_chunk : expand_chunk;
        Py_ssize_t parents = caps[d] < step ? caps[d] : step;
        caps[d + 1] = depth - d >= 2 ? parents * Z : 0;
        if (depth - d >= 2 && parents > widest)
            widest = parents;
    }
    size_t scratch = (size_t)S + Z + 3 * (size_t)A + 8, block = leaf_scratch(t);
    doubles += scratch + block + (size_t)n * A * 2 /* root rho, Q */ + (size_t)widest + A;
    ints += 2 * (size_t)n;
    idx += 2 * (size_t)A + 1;
    size_t bytes = doubles * sizeof(double) + ints * sizeof(int) + idx * sizeof(Py_ssize_t)
                   + (depth + 1) * sizeof(Level);
    char *mem = PyMem_RawMalloc(bytes);
    if (!mem) {
        PyErr_NoMemory();
        goto release_Q;
    }
    Level *lev = (Level *)mem;
    double *dp = (double *)(mem + (depth + 1) * sizeof(Level));
    for (long d = 1; d < depth; d++) {
        Level *L = &lev[d];
        L->cap = caps[d];
        L->B = dp; dp += caps[d] * S;
        L->rho = dp; dp += caps[d] * A;
        L->Q = dp; dp += caps[d] * A;
        L->eta = dp; dp += caps[d];
        L->V = dp; dp += caps[d];
    }
    c.scratch = dp; dp += scratch;
    c.block = dp; dp += block;
    c.acc = dp; dp += widest;
    double *cost0 = dp; dp += A;
    double *rho0 = dp; dp += n * A;
    double *Q0 = dp; dp += n * A;
    double *B0 = (double *)vB.buf;
    Py_ssize_t *ip = (Py_ssize_t *)dp;
    for (long d = 1; d < depth; d++) {
        lev[d].par = ip;
        ip += caps[d];
    }
    Py_ssize_t *order0 = ip; ip += A;
    c.order = ip; ip += A + 1;
    int *np_ = (int *)ip;
    for (long d = 1; d < depth; d++) {
        lev[d].lo = np_; np_ += caps[d];
        lev[d].up = np_; np_ += caps[d];
    }
    Level *R = &lev[0];
    R->cap = n;
    R->rho = rho0;
    R->Q = have_Q ? (double *)vQ.buf : Q0;
    R->lo = np_; np_ += n;
    R->up = np_; np_ += n;
    for (Py_ssize_t a = 0; a < A; a++) {
        cost0[a] = have_cost ? ((double *)vcost.buf)[a] : 0.0;
        c.order[a] = a;
    }
    c.cost = cost0;
    c.lev = lev;
    int64_t sizes[1002];
    memset(sizes, 0, (depth + 1) * sizeof(int64_t));
    sizes[0] = n;
    c.sizes = sizes;
    if (atol >= 0.0) {
        Py_ssize_t bad = check_rows(B0, n, S, atol);
        if (bad >= 0) {
            result = Py_BuildValue("(inOii)", 2, bad, Py_None, -1, -1);
            goto free_mem;
        }
    }
    R->B = B0;

    /* the roots: rho, bounds, the allowed actions and their order */
    int bounded = use_bounds && t->Cg != NULL, lo0 = -1, up0 = -1;
    for (Py_ssize_t p = 0; p < n; p++) {
        int lo, up;
        node_info(&c, R->B + p * S, R->rho + p * A, &lo, &up, c.scratch);
        R->lo[p] = all_root ? 0 : lo;
        R->up[p] = all_root ? (int)A - 1 : up;
        if (p == 0 && bounded) {
            lo0 = lo;
            up0 = up;
        }
    }
    if (rho_order) {
        Ranked stack[64];
        Ranked *buf = A <= 64 ? stack : PyMem_RawMalloc(A * sizeof(Ranked));
        if (!buf) {
            PyErr_NoMemory();
            goto free_mem;
        }
        for (Py_ssize_t a = 0; a < A; a++) {
            buf[a].rho = R->rho[a];
            buf[a].a = a;
        }
        qsort(buf, A, sizeof(Ranked), by_rho);
        for (Py_ssize_t a = 0; a < A; a++)
            order0[a] = buf[a].a;
        if (buf != stack)
            PyMem_RawFree(buf);
    } else {
        for (Py_ssize_t a = 0; a < A; a++)
            order0[a] = a;
    }
    c.order0 = order0;

    int status = DONE;
    if (depth == 0) {
        for (Py_ssize_t i = 0; i < n * A; i++)
            R->Q[i] = R->rho[i];
    } else {
        c.save = PyEval_SaveThread();
        status = level_values(&c, 0, n, (int)depth);
        PyEval_RestoreThread(c.save);
    }
    if (status == FAILED) {
        if (!PyErr_Occurred())
            PyErr_SetString(PyExc_RuntimeError, "search kernel failed");
        goto free_mem;
    }
    int best = -1;
    if (!count_only) {
        for (Py_ssize_t a = 0; a < A; a++) {
            double q = R->Q[a];
            if (q == -INFINITY)
                continue;
            if (best < 0 || q > R->Q[best])
                best = (int)a;
        }
        for (Py_ssize_t i = 0; i < n * A; i++)
            if (R->Q[i] == -INFINITY)
                R->Q[i] = NAN;
    }
    PyObject *tsizes = PyTuple_New(depth + 1);
    if (!tsizes)
        goto free_mem;
    for (long d = 0; d <= depth; d++) {
        PyObject *v = PyLong_FromLongLong(sizes[d]);
        if (!v) {
            Py_DECREF(tsizes);
            goto free_mem;
        }
        PyTuple_SET_ITEM(tsizes, d, v);
    }
    result = Py_BuildValue("(iiNii)", status, best, tsizes, lo0, up0);
free_mem:
    PyMem_RawFree(mem);
release_Q:
    if (have_Q)
        PyBuffer_Release(&vQ);
release_cost:
    if (have_cost)
        PyBuffer_Release(&vcost);
release_B:
    PyBuffer_Release(&vB);
    return result;
}

/* ------------------------------------------------------------------- small entry points */

static PyObject *kernel_monotonic(PyObject *module, PyObject *unused)
{
    return PyFloat_FromDouble(monotonic_now());
}

/* log_array(x, out): out[i] = log(x[i]) by the kernel's logarithm (for its accuracy test). */
static PyObject *kernel_log_array(PyObject *module, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "log_array: 2 arguments expected");
        return NULL;
    }
    Py_buffer vx, vo;
    if (PyObject_GetBuffer(args[0], &vx, PyBUF_C_CONTIGUOUS) < 0)
        return NULL;
    if (!get_buffer(args[1], &vo, vx.len / 8, 1, "out")) {
        PyBuffer_Release(&vx);
        return NULL;
    }
    const double *x = vx.buf;
    double *o = vo.buf;
    for (Py_ssize_t i = 0; i < vx.len / 8; i++)
        o[i] = x[i] > 0.0 && isfinite(x[i]) ? klog(x[i]) : NAN;
    PyBuffer_Release(&vx);
    PyBuffer_Release(&vo);
    Py_RETURN_NONE;
}

static PyMethodDef kernel_methods[] = {
    {"search", (PyCFunction)(void (*)(void))kernel_search, METH_FASTCALL,
     "search(tables, B, n, depth, use_bounds, all_root, rho_order, cost, leaf_chunk, expand_chunk, deadline, "
     "clock, first_free, count_only, Q, rho, lohi, sizes) -> status (0 done, 1 deadline)"},
    {"monotonic", kernel_monotonic, METH_NOARGS, "The native monotonic clock (seconds)."},
    {"log_array", (PyCFunction)(void (*)(void))kernel_log_array, METH_FASTCALL,
     "log_array(x, out): the kernel's logarithm of every x (float64)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef kernel_module = {
    PyModuleDef_HEAD_INIT, "_pomdp_planner_kernel",
    "The compiled search kernel of pomdp_planner (see pomdp_planner/core/search_kernel.py).", -1, kernel_methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__pomdp_planner_kernel(void)
{
    if (PyType_Ready(&TablesType) < 0)
        return NULL;
    PyObject *m = PyModule_Create(&kernel_module);
    if (!m)
        return NULL;
    Py_INCREF(&TablesType);
    if (PyModule_AddObject(m, "Tables", (PyObject *)&TablesType) < 0
        || PyModule_AddIntConstant(m, "KERNEL_VERSION", KERNEL_VERSION) < 0
        || PyModule_AddIntConstant(m, "PAD", PAD) < 0
        || PyModule_AddObject(m, "ETA_SKIP", PyFloat_FromDouble(ETA_SKIP)) < 0
        || PyModule_AddObject(m, "ETA_FUSED_MIN", PyFloat_FromDouble(ETA_FUSED_MIN)) < 0
        || PyModule_AddObject(m, "TIE_RTOL", PyFloat_FromDouble(TIE_RTOL)) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
