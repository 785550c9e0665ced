/*
 * A standalone, hand-optimised C implementation of the exhaustive depth-d expectimax that
 * pomdp_planner's search computes (paper Algorithm 1 without pruning; depth and node counting of
 * Table II): the yardstick of `pomdp-planner bench search` (pomdp_planner/bench/kernel_bench.py
 * compiles it with the machine's cc, -O3 -march=native -ffast-math, into a temporary directory
 * and calls it through ctypes; it is never part of the planner).
 *
 * Level-wise, breadth first: every level is one contiguous n x S array of beliefs (all of it in
 * memory: this is a benchmark, not a planner); the leaf level is fused (no posterior is formed):
 * per (parent, action) one product of the predicted belief b^a with the table [O | O r_a'] gives
 * eta and u . r_a' for every observation, and (b^a)^2 @ O^2 (Renyi) or the two products of
 * sum_s u_s log u_s (Shannon) the uncertainty term; the logarithms of a block of 32 parents (all
 * their actions and observations) are taken in one loop that the compiler vectorises (glibc's
 * vector log under -ffast-math). Branches with eta <= 1e-300 are impossible and skipped; leaves
 * with eta < 1e-100 are valued from the normalised posterior, as in the package.
 *
 * Conventions as in the package: P[a][i][j], O[a][s][z], r[s][a], rho(b, a) = r_a . b - w_a f(b).
 */

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define ETA_SKIP 1e-300
#define ETA_FUSED_MIN 1e-100
#define BLOCK 32

typedef struct {
    int S, A, Z, kind; /* kind: 0 none, 1 Renyi-2, 2 Shannon */
    double gamma;
    const double *P, *O, *w;
    double *rT;  /* A x S */
    int Zp;      /* Z rounded up to a multiple of 8 (the blocks of W and X) */
    double *W;   /* A x S x (A + 1) Zp: [O[a][s][z] | O[a][s][z] r[s][a']], zero-padded */
    double *X;   /* A x S x Zp: O^2 or O log O, zero-padded */
    double *OT;  /* A x Z x S */
} Model;

/* CPU time of the calling thread (the benchmark compares CPU times: the machine may be shared). */
static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

static double entropy(const Model *m, const double *b)
{
    double f = 0.0;
    if (m->kind == 1) {
        for (int s = 0; s < m->S; s++)
            f += b[s] * b[s];
        return -log(f);
    }
    if (m->kind == 2) {
        for (int s = 0; s < m->S; s++)
            if (b[s] > 0.0)
                f -= b[s] * log(b[s]);
        return f;
    }
    return 0.0;
}

static void rho(const Model *m, const double *b, double *out)
{
    double f = entropy(m, b);
    for (int a = 0; a < m->A; a++) {
        double v = 0.0;
        for (int s = 0; s < m->S; s++)
            v += m->rT[a * m->S + s] * b[s];
        out[a] = v - m->w[a] * f;
    }
}

/* y[0..m) = sum_i x[i] M[i ld + 0..m), columns in register tiles of 8 (m a multiple of 8 or not). */
typedef double v8d __attribute__((vector_size(64)));

static inline void gemv(const double *restrict x, int n, const double *restrict M, int ld, int m, double *restrict y)
{
    int q = 0;
    for (; q + 8 <= m; q += 8) {
        v8d acc = {0};
        for (int i = 0; i < n; i++) {
            v8d r;
            memcpy(&r, M + (size_t)i * ld + q, sizeof(r));
            acc += x[i] * r;
        }
        memcpy(y + q, &acc, sizeof(acc));
    }
    for (; q < m; q++) {
        double acc = 0.0;
        for (int i = 0; i < n; i++)
            acc += x[i] * M[(size_t)i * ld + q];
        y[q] = acc;
    }
}

static void predict(const Model *m, const double *b, int a, double *ba)
{
    gemv(b, m->S, m->P + (size_t)a * m->S * m->S, m->S, m->S, ba);
}

/* Children of n beliefs B: C (n A Z x S at most), their parent key (i A + a) and eta. */
static long expand(const Model *m, const double *B, long n, double *C, long *key, double *eta)
{
    int S = m->S, A = m->A, Z = m->Z;
    double ba[4096], e[4096];
    long k = 0;
    for (long i = 0; i < n; i++)
        for (int a = 0; a < A; a++) {
            predict(m, B + i * S, a, ba);
            const double *O = m->O + (size_t)a * S * Z;
            for (int z = 0; z < Z; z++)
                e[z] = 0.0;
            for (int s = 0; s < S; s++)
                for (int z = 0; z < Z; z++)
                    e[z] += ba[s] * O[s * Z + z];
            for (int z = 0; z < Z; z++) {
                if (!(e[z] > ETA_SKIP))
                    continue;
                const double *ot = m->OT + ((size_t)a * Z + z) * S;
                for (int s = 0; s < S; s++)
                    C[k * S + s] = ba[s] * ot[s] / e[z];
                key[k] = i * A + a;
                eta[k] = e[z];
                k++;
            }
        }
    return k;
}

/* QL[i A + a] = sum_z eta V(leaf) for the leaf parents B (n x S); returns the number of leaves. */
static long leaves(const Model *m, const double *B, long n, double *QL)
{
    int S = m->S, A = m->A, Z = m->Z, Zp = m->Zp, K = (A + 1) * Zp;
    size_t per = (size_t)A * Z;
    double *Y = malloc(sizeof(double) * BLOCK * A * K), *T = malloc(sizeof(double) * BLOCK * A * Zp);
    double *L = malloc(sizeof(double) * BLOCK * per), *BA = malloc(sizeof(double) * BLOCK * A * S);
    double *Eb = malloc(sizeof(double) * BLOCK * per);
    double ba2[4096], lb[4096], tz[4096], best[4096];
    long count = 0;
    for (long i0 = 0; i0 < n; i0 += BLOCK) {
        int nb = n - i0 < BLOCK ? (int)(n - i0) : BLOCK;
        for (int i = 0; i < nb; i++)
            for (int a = 0; a < A; a++) {
                size_t ia = (size_t)i * A + a;
                double *ba = BA + ia * S, *y = Y + ia * K, *t = T + ia * Zp;
                predict(m, B + (i0 + i) * S, a, ba);
                gemv(ba, S, m->W + (size_t)a * S * K, K, K, y); /* eta and u . r_a' for every a' */
                if (m->kind == 1) {
                    for (int s = 0; s < S; s++)
                        ba2[s] = ba[s] * ba[s];
                    gemv(ba2, S, m->X + (size_t)a * S * Zp, Zp, Zp, t);
                } else if (m->kind == 2) {
                    for (int s = 0; s < S; s++)
                        lb[s] = ba[s] > 0.0 ? ba[s] * log(ba[s]) : 0.0;
                    gemv(ba, S, m->X + (size_t)a * S * Zp, Zp, Zp, t);
                    gemv(lb, S, m->W + (size_t)a * S * K, K, Zp, ba2); /* sum_s ba log ba O */
                    for (int z = 0; z < Zp; z++)
                        t[z] += ba2[z];
                }
                memcpy(Eb + ia * Z, y, sizeof(double) * Z);
                double *arg = L + ia * Z; /* the logarithms' arguments (1 where eta is too small) */
                for (int z = 0; z < Z; z++)
                    arg[z] = y[z] >= ETA_FUSED_MIN ? (m->kind == 1 ? t[z] / (y[z] * y[z]) : y[z]) : 1.0;
            }
        /* the block's logarithms in one loop */
        long nl = (long)nb * per;
        if (m->kind != 0)
            for (long j = 0; j < nl; j++)
                L[j] = log(L[j]);
        for (int i = 0; i < nb; i++)
            for (int a = 0; a < A; a++) {
                size_t ia = (size_t)i * A + a;
                const double *y = Y + ia * K, *t = T + ia * Zp, *l = L + ia * Z, *e = Eb + ia * Z;
                for (int z = 0; z < Z; z++)
                    tz[z] = m->kind == 1 ? e[z] * l[z] : (m->kind == 2 ? t[z] - e[z] * l[z] : 0.0);
                for (int z = 0; z < Z; z++)
                    best[z] = y[Zp + z] + m->w[0] * tz[z];
                for (int k = 1; k < A; k++)
                    for (int z = 0; z < Z; z++) {
                        double v = y[(k + 1) * Zp + z] + m->w[k] * tz[z];
                        best[z] = v > best[z] ? v : best[z];
                    }
                double total = 0.0;
                for (int z = 0; z < Z; z++) {
                    double ez = e[z];
                    if (!(ez > ETA_SKIP))
                        continue;
                    count++;
                    if (m->kind != 0 && ez < ETA_FUSED_MIN) { /* from the normalised posterior */
                        double tau[4096], rr[4096];
                        const double *ba = BA + ia * S, *ot = m->OT + ((size_t)a * Z + z) * S;
                        for (int s = 0; s < S; s++)
                            tau[s] = ba[s] * ot[s] / ez;
                        rho(m, tau, rr);
                        double bz = rr[0];
                        for (int k = 1; k < A; k++)
                            bz = rr[k] > bz ? rr[k] : bz;
                        total += ez * bz;
                        continue;
                    }
                    total += best[z];
                }
                QL[(i0 + i) * A + a] = total;
            }
    }
    free(Y); free(T); free(L); free(BA); free(Eb);
    return count;
}

/*
 * The root Q values (A) of the exhaustive depth-``depth`` search from b0, the belief nodes of the
 * tree (root and leaves included) in *nodes, and the mean CPU time of the calling thread over
 * ``reps`` runs in *seconds (the tables are built once, before).
 * Returns 0, or -1 when memory runs out.
 */
int expectimax(int S, int A, int Z, double gamma, int kind, const double *P, const double *O, const double *r,
               const double *w, const double *b0, int depth, int reps, double *Q, long long *nodes, double *seconds)
{
    int Zp = (Z + 7) / 8 * 8, K = (A + 1) * Zp;
    Model m = {S, A, Z, kind, gamma, P, O, w, NULL, Zp, NULL, NULL, NULL};
    m.rT = malloc(sizeof(double) * A * S);
    m.W = calloc((size_t)A * S * K, sizeof(double));
    m.X = kind ? calloc((size_t)A * S * Zp, sizeof(double)) : NULL;
    m.OT = malloc(sizeof(double) * (size_t)A * Z * S);
    for (int s = 0; s < S; s++)
        for (int a = 0; a < A; a++)
            m.rT[a * S + s] = r[s * A + a];
    for (int a = 0; a < A; a++)
        for (int s = 0; s < S; s++)
            for (int z = 0; z < Z; z++) {
                double o = O[((size_t)a * S + s) * Z + z];
                m.W[((size_t)a * S + s) * K + z] = o;
                for (int k = 0; k < A; k++)
                    m.W[((size_t)a * S + s) * K + (k + 1) * Zp + z] = o * r[s * A + k];
                if (kind == 1)
                    m.X[((size_t)a * S + s) * Zp + z] = o * o;
                else if (kind == 2)
                    m.X[((size_t)a * S + s) * Zp + z] = o > 0.0 ? o * log(o) : 0.0;
                m.OT[((size_t)a * Z + z) * S + s] = o;
            }
    /* level sizes of the complete tree bound the arrays */
    long cap[64];
    cap[0] = 1;
    for (int d = 1; d <= depth; d++)
        cap[d] = cap[d - 1] * A * Z;
    double *Bl[64], *E[64], *R[64];
    long *Kl[64];
    for (int d = 0; d < depth; d++) {
        Bl[d] = malloc(sizeof(double) * cap[d] * S);
        R[d] = malloc(sizeof(double) * cap[d] * A);
        Kl[d] = malloc(sizeof(long) * cap[d]);
        E[d] = malloc(sizeof(double) * cap[d]);
        if (!Bl[d] || !R[d] || !Kl[d] || !E[d])
            return -1;
    }
    double *QL = malloc(sizeof(double) * cap[depth - 1] * A), *V = malloc(sizeof(double) * cap[depth - 1]);
    double *Vn = malloc(sizeof(double) * cap[depth - 1]);
    if (!QL || !V || !Vn)
        return -1;
    double t0 = now();
    for (int rep = 0; rep < reps; rep++) {
        long n[64];
        n[0] = 1;
        memcpy(Bl[0], b0, sizeof(double) * S);
        long long total = 1;
        for (int d = 0; d + 1 < depth; d++) {
            n[d + 1] = expand(&m, Bl[d], n[d], Bl[d + 1], Kl[d + 1], E[d + 1]);
            total += n[d + 1];
        }
        int d = depth - 1;
        total += leaves(&m, Bl[d], n[d], QL);
        /* back up: V of level d, then the levels above */
        for (; d >= 0; d--) {
            for (long i = 0; i < n[d]; i++) {
                rho(&m, Bl[d] + i * S, R[d] + i * A);
                double v = -INFINITY;
                for (int a = 0; a < A; a++) {
                    double q = R[d][i * A + a] + gamma * QL[i * A + a];
                    if (d == 0)
                        Q[a] = q;
                    v = q > v ? q : v;
                }
                V[i] = v;
            }
            if (d == 0)
                break;
            /* QL of level d - 1 from the values of level d */
            for (long i = 0; i < n[d - 1] * A; i++)
                QL[i] = 0.0;
            for (long i = 0; i < n[d]; i++)
                QL[Kl[d][i]] += E[d][i] * V[i];
        }
        *nodes = total;
    }
    *seconds = (now() - t0) / reps;
    for (int d = 0; d < depth; d++) {
        free(Bl[d]); free(R[d]); free(Kl[d]); free(E[d]);
    }
    free(QL); free(V); free(Vn); free(m.rT); free(m.W); free(m.X); free(m.OT);
    return 0;
}
