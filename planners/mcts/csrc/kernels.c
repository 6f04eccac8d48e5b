/* The search kernels of mcts's thts engine (planners/mcts/ckernels.py).

   Compiled in one unit after the instance's step and rddl/sim/csrc/step_api.c
   (rddl/sim/csrc/step.h stands in for them when this file is read alone): loops that
   call the step many times, so that one call from Python does a whole piece
   of work.

   * `ippc_probe`: every candidate action of a state under two fixed draw
     vectors; which actions are deterministic, which are equivalent;
   * `ippc_ids_values`: PROST's IDS on the most-likely determinisation (every
     uniform 0.5, every normal 0), with a (depth, state) value cache;
   * `ippc_enum`: the legal joint actions of a state, built from the
     groundings legal alone and extended while legal;
   * `ippc_walk`, `ippc_walk_enum`: roll-outs. */
#ifndef IPPC_STEP_UNIT
#include "../../../rddl/sim/csrc/step.h"
#include "../../../rddl/sim/csrc/step_api.c"
#endif

static uint64_t hash_bytes(const void *p, size_t n, uint64_t h) {
    const unsigned char *b = (const unsigned char *)p;
    for (size_t i = 0; i < n; i++) { h ^= b[i]; h *= 0x100000001B3ULL; }
    return h;
}
/* -0.0 and 0.0 are one state, as in Python */
static uint64_t hash_state(const double *x, int n, uint64_t h) {
    for (int i = 0; i < n; i++) { double v = x[i] == 0 ? 0.0 : x[i]; h = hash_bytes(&v, sizeof v, h); }
    return h;
}
static int same(const double *a, const double *b, int n) {
    for (int i = 0; i < n; i++) if (!(a[i] == b[i] || (a[i] != a[i] && b[i] != b[i]))) return 0;
    return 1;
}


static int deterministic(const double *L) {
    for (int i = 0; i < NL; i++) {
        double p = L[i];
        if (p < 0) continue;            /* not reached */
        if (p >= 2.0) { if (p != 2.0) return 0; }
        else if (p > 0.0 && p < 1.0) return 0;
        else if (p != p) return 0;
    }
    return 1;
}

/* Probe `n` actions (rows of ACTS) in S under two draw vectors. Out per action:
   N1 (n x NS) and R1, D1 the first probe's successor, reward, done; DET whether
   no draw decided anything; SAMER whether both probes gave the same reward;
   KEEP 1 for the first of each class of equivalent actions, else 0. Only
   deterministic actions are merged: two stochastic actions that agree on both
   probes may agree by chance (the probes' draws are fixed for the session), so
   each stochastic action is kept (tests/data/mcts_sound/probe.rddl). */
int ippc_probe(const double *S, const double *ACTS, int n,
               const double *U1, const double *Z1, const double *U2, const double *Z2,
               double *N1, double *R1, int *D1, int *DET, int *SAMER, int *KEEP) {
    int W = 2 * NL + 2 * NS + 4;                 /* a signature's width */
    double *sig = (double *)malloc(sizeof(double) * (size_t)W * (size_t)(n > 0 ? n : 1));
    uint64_t *hs = (uint64_t *)malloc(sizeof(uint64_t) * (size_t)(n > 0 ? n : 1));
    if (!sig || !hs) { free(sig); free(hs); return -1; }
    int kept = 0;
    for (int a = 0; a < n; a++) {
        double *g = sig + (size_t)a * W;
        double *L1 = g, *L2 = g + NL, *n1 = g + 2 * NL, *n2 = n1 + NS;
        double d = 0.0, r1 = 0.0, r2 = 0.0;
        for (int i = 0; i < 2 * NL; i++) g[i] = -1.0;
        step(S, ACTS + (size_t)a * NA, U1, Z1, n1, &r1, &d, L1);
        int det = deterministic(L1);
        double d1 = d != 0, d2 = 0.0;
        if (det) {
            memcpy(n2, n1, sizeof(double) * NS); r2 = r1; d2 = d1;
            for (int i = 0; i < NL; i++) L2[i] = -2.0;   /* one probe */
        } else {
            d = 0.0;
            step(S, ACTS + (size_t)a * NA, U2, Z2, n2, &r2, &d, L2);
            d2 = d != 0;
        }
        g[2 * NL + 2 * NS] = r1; g[2 * NL + 2 * NS + 1] = d1;
        g[2 * NL + 2 * NS + 2] = r2; g[2 * NL + 2 * NS + 3] = d2;
        memcpy(N1 + (size_t)a * NS, n1, sizeof(double) * NS);
        R1[a] = r1; D1[a] = (int)d1; DET[a] = det; SAMER[a] = r1 == r2;
        uint64_t h = hash_state(g, W, 1469598103934665603ULL);
        hs[a] = h;
        int dup = 0;
        for (int b = 0; b < a && !dup && det; b++)
            if (KEEP[b] && DET[b] && hs[b] == h && same(sig + (size_t)b * W, g, W)) dup = 1;
        KEEP[a] = !dup;
        kept += !dup;
    }
    free(sig); free(hs);
    return kept;
}

/* ---- IDS on the most-likely determinisation, with a (depth, state) cache ---- */
typedef struct { uint64_t key; double value; } entry;
static entry *cache = 0;
static size_t cache_cap = 0, cache_used = 0;
static double LU[NU + 1], LZ[NZ + 1];
static const double *IDS_ACTS = 0;
static int IDS_N = 0;
static long ids_steps = 0;
static long ids_token = -1;
/* Candidates that depend on the state: a caller's function that writes the
   legal candidates of S (at most cap rows of NA) into OUT and their ids into
   IDX, and returns their number (-need when cap is too small). */
typedef int (*cands_fn)(const double *S, double *OUT, int cap, int *IDX);
static cands_fn IDS_CB = 0;

/* The candidates of S from `cb` in a block of its own (free it); -1: none. */
static int cands_of(cands_fn cb, const double *S, double **OUT, int **IDX) {
    int cap = 64;
    for (int tries = 0; tries < 4; tries++) {
        double *out = (double *)malloc(sizeof(double) * NA * (size_t)cap);
        int *idx = (int *)malloc(sizeof(int) * (size_t)cap);
        if (!out || !idx) { free(out); free(idx); return -1; }
        int n = cb(S, out, cap, idx);
        if (n >= 0) { *OUT = out; *IDX = idx; return n; }
        free(out); free(idx);
        cap = -n;
    }
    return -1;
}

void ippc_ids_clear(void) { if (cache) memset(cache, 0, sizeof(entry) * cache_cap); cache_used = 0; }

static int cache_get(uint64_t key, double *v) {
    if (!cache) return 0;
    size_t i = (size_t)key & (cache_cap - 1);
    while (cache[i].key) { if (cache[i].key == key) { *v = cache[i].value; return 1; } i = (i + 1) & (cache_cap - 1); }
    return 0;
}
static void cache_put(uint64_t key, double v) {
    if (!cache) {
        cache_cap = (size_t)1 << 20;
        cache = (entry *)calloc(cache_cap, sizeof(entry));
        if (!cache) { cache_cap = 0; return; }
    }
    if (cache_used * 2 > cache_cap) ippc_ids_clear();
    size_t i = (size_t)key & (cache_cap - 1);
    while (cache[i].key) { if (cache[i].key == key) { cache[i].value = v; return; } i = (i + 1) & (cache_cap - 1); }
    cache[i].key = key; cache[i].value = v; cache_used++;
}

static double ids(const double *S, int depth, double gamma) {
    uint64_t key = hash_state(S, NS, 1469598103934665603ULL ^ (uint64_t)depth * 0x9E3779B97F4A7C15ULL);
    if (!key) key = 1;
    double v;
    if (cache_get(key, &v)) return v;
    double best = -INFINITY, l[NL + 1];
    const double *acts = IDS_ACTS;
    int nacts = IDS_N;
    double *own = 0;
    int *own_idx = 0;
    if (IDS_CB) {
        nacts = cands_of(IDS_CB, S, &own, &own_idx);
        if (nacts < 0) nacts = 0;
        acts = own;
    }
    double *nx = (double *)malloc(sizeof(double) * (size_t)(NS + 1) * (size_t)(nacts > 0 ? nacts : 1));
    uint64_t *seen = (uint64_t *)malloc(sizeof(uint64_t) * (size_t)(nacts > 0 ? nacts : 1));
    int nseen = 0;
    for (int a = 0; a < nacts && nx && seen; a++) {
        double *n = nx + (size_t)nseen * (NS + 1), r = 0.0, d = 0.0;
        step(S, acts + (size_t)a * NA, LU, LZ, n, &r, &d, l);
        ids_steps++;
        n[NS] = r;
        uint64_t h = hash_state(n, NS + 1, 1469598103934665603ULL);
        int dup = 0;
        for (int b = 0; b < nseen && !dup; b++)
            if (seen[b] == h && same(nx + (size_t)b * (NS + 1), n, NS + 1)) dup = 1;
        if (dup) continue;
        seen[nseen++] = h;
        if (d == 0 && depth > 1) r += gamma * ids(n, depth - 1, gamma);
        if (r > best) best = r;
    }
    free(nx); free(seen); free(own); free(own_idx);
    if (best == -INFINITY) best = 0.0;
    cache_put(key, best);
    return best;
}

/* Each of the n actions KEPT: its reward plus gamma times the depth-(depth-1)
   IDS value of its most-likely successor (its reward alone when that ends the
   run or depth <= 1); the recursion takes the ncand actions CANDS. `token`
   names the caller's candidates and gamma: another token clears the cache.
   Returns the steps made. */
long ippc_ids_values(const double *S, const double *KEPT, int n, const double *CANDS,
                     int ncand, int depth, double gamma, double *OUT, long token) {
    /* the cache holds one caller's values (its candidates, its gamma) */
    if (token != ids_token) { ippc_ids_clear(); ids_token = token; }
    IDS_ACTS = CANDS; IDS_N = ncand; ids_steps = 0;
    for (int i = 0; i < NU; i++) LU[i] = 0.5;
    for (int i = 0; i < NZ; i++) LZ[i] = 0.0;
    double l[NL + 1], nx[NS + 1];
    for (int a = 0; a < n; a++) {
        double r = 0.0, d = 0.0;
        step(S, KEPT + (size_t)a * NA, LU, LZ, nx, &r, &d, l);
        ids_steps++;
        OUT[a] = (d != 0 || depth <= 1) ? r : r + gamma * ids(nx, depth - 1, gamma);
    }
    return ids_steps;
}

/* ---- the legal joint actions of a state ---- */
/* The groundings a joint action may set (EN_POS[g] to EN_VAL[g], the others at
   noop's values), at most EN_K of them at once; EN_LIMIT: most actions counted. */
static double *EN_NOOP = 0, *EN_VAL = 0;
static int *EN_POS = 0;
static int EN_NG = 0, EN_K = 0, EN_LIMIT = 0, EN_READY = 0;

int ippc_enum_setup(const double *NOOP, const int *POS, const double *VAL, int ng, int k, int limit) {
    free(EN_NOOP); free(EN_VAL); free(EN_POS);
    EN_NOOP = (double *)malloc(sizeof(double) * NA);
    EN_VAL = (double *)malloc(sizeof(double) * (size_t)(ng > 0 ? ng : 1));
    EN_POS = (int *)malloc(sizeof(int) * (size_t)(ng > 0 ? ng : 1));
    EN_READY = 0;
    if (!EN_NOOP || !EN_VAL || !EN_POS) return -1;
    memcpy(EN_NOOP, NOOP, sizeof(double) * NA);
    if (ng) { memcpy(EN_VAL, VAL, sizeof(double) * (size_t)ng); memcpy(EN_POS, POS, sizeof(int) * (size_t)ng); }
    EN_NG = ng; EN_K = k; EN_LIMIT = limit; EN_READY = 1;
    return 0;
}

typedef struct { const double *S; double *A; int *L; int nl; int *chosen; int count, cap; int *G; double *OUT; } en_walk;

static void en_emit(en_walk *w, int size) {
    if (w->count < w->cap) {
        if (w->G) for (int i = 0; i < EN_K; i++) w->G[(size_t)w->count * EN_K + i] = i < size ? w->chosen[i] : -1;
        if (w->OUT) memcpy(w->OUT + (size_t)w->count * NA, w->A, sizeof(double) * NA);
    }
    w->count++;
}

static void en_rec(en_walk *w, int start, int size) {
    for (int i = start; i < w->nl && w->count <= EN_LIMIT; i++) {
        int g = w->L[i], p = EN_POS[g];
        double keep = w->A[p];
        w->A[p] = EN_VAL[g];
        w->chosen[size] = g;
        /* (one grounding alone was checked already) */
        if (size == 0 || legal(w->S, w->A)) {
            en_emit(w, size + 1);
            if (size + 1 < EN_K) en_rec(w, i + 1, size + 1);
        }
        w->A[p] = keep;
    }
}

/* The legal joint actions of S (noop first, then by the groundings set, in
   order) built from the groundings that are legal alone, and extended only
   while legal: complete where the constraints are monotone (every part of a
   legal joint action is legal), which the caller checks against the solver.
   The first `cap` are written (their groundings into G, EN_K a row, -1 after
   the last; their vectors into OUT; either may be NULL). Returns how many
   there are (EN_LIMIT + 1: more than EN_LIMIT), or -1 where noop is illegal
   or nothing was set up. */
int ippc_enum(const double *S, int cap, int *G, double *OUT) {
    if (!EN_READY) return -1;
    double A[NA];
    memcpy(A, EN_NOOP, sizeof(double) * NA);
    if (!legal(S, A)) return -1;
    int *L = (int *)malloc(sizeof(int) * (size_t)(EN_NG > 0 ? EN_NG : 1));
    int chosen[EN_K > 0 ? EN_K : 1];
    if (!L) return -1;
    int nl = 0;
    for (int g = 0; g < EN_NG; g++) {
        int p = EN_POS[g];
        double keep = A[p];
        A[p] = EN_VAL[g];
        if (legal(S, A)) L[nl++] = g;
        A[p] = keep;
    }
    en_walk w = {S, A, L, nl, chosen, 0, cap, G, OUT};
    en_emit(&w, 0);
    if (EN_K > 0) en_rec(&w, 0, 0);
    free(L);
    return w.count;
}

/* `cands_fn` over `ippc_enum` (for IDS): the first EN_LIMIT where there are more. */
static int enum_cb(const double *S, double *OUT, int cap, int *IDX) {
    int n = ippc_enum(S, cap, 0, OUT);
    if (n < 0) return 0;
    if (n > EN_LIMIT) n = EN_LIMIT;
    if (n > cap) return -n;
    for (int i = 0; i < n; i++) IDX[i] = -1;
    return n;
}

/* A roll-out of up to `n` steps from S where each step's action is noop or one
   grounding of `ippc_enum_setup`'s, drawn uniformly among the ng + 1 and drawn
   again (up to 8 times) while it is illegal in the state, then noop: about
   uniform over noop and the groundings legal alone, at a few `legal` calls a
   step. As `ippc_walk` otherwise (`walk_steps` below). */
static double walk_steps(const double *S, int n, const double *POOL, int npool, const double *NOOP,
                         int groundings, double gamma, uint64_t *rng, int *TAKEN);
double ippc_walk_enum(const double *S, int n, double gamma, uint64_t *rng, int *TAKEN) {
    return walk_steps(S, n, 0, 0, EN_NOOP, 1, gamma, rng, TAKEN);
}

/* `ippc_ids_values` with the candidates of every state from `ippc_enum`. */
long ippc_ids_values_enum(const double *S, const double *KEPT, int n, int depth, double gamma,
                          double *OUT, long token) {
    cands_fn before = IDS_CB;
    IDS_CB = enum_cb;
    long steps = ippc_ids_values(S, KEPT, n, 0, 0, depth, gamma, OUT, token);
    IDS_CB = before;
    return steps;
}

/* `ippc_ids_values` with the candidates of every state from the caller's `cb`
   (state-dependent legality: the chooser's candidates, as the tree's nodes get them). */
long ippc_ids_values_cb(const double *S, const double *KEPT, int n, cands_fn cb, int depth,
                        double gamma, double *OUT, long token) {
    cands_fn before = IDS_CB;
    IDS_CB = cb;
    long steps = ippc_ids_values(S, KEPT, n, 0, 0, depth, gamma, OUT, token);
    IDS_CB = before;
    return steps;
}

/* A roll-out of up to `n` steps from S: noop (npool 0) or actions drawn
   uniformly from POOL (redrawn up to 8 times where illegal in the state,
   then noop). *TAKEN: the steps made, negated when the run ended. */
double ippc_walk(const double *S, int n, const double *POOL, int npool, const double *NOOP,
                 double gamma, uint64_t *rng, int *TAKEN) {
    return walk_steps(S, n, POOL, npool, NOOP, 0, gamma, rng, TAKEN);
}

/* The roll-outs' loop: each step's action from POOL (`ippc_walk`) or, with
   `groundings`, noop or one legal grounding (`ippc_walk_enum`). */
static double walk_steps(const double *S, int n, const double *POOL, int npool, const double *NOOP,
                         int groundings, double gamma, uint64_t *rng, int *TAKEN) {
    double s[NS + 1], nx[NS + 1], U[NU + 1], Z[NZ + 1], l[NL + 1], G[NA];
    memcpy(s, S, sizeof(double) * NS);
    double total = 0.0, disc = 1.0;
    int taken = 0, ended = 0;
    for (int t = 0; t < n; t++) {
        const double *A = NOOP;
        if (groundings) {
            memcpy(G, NOOP, sizeof(double) * NA);
            A = G;
            if (EN_READY && EN_NG > 0) {
                for (int k = 0; k < 8; k++) {
                    uint64_t pick = next64(rng) % (uint64_t)(EN_NG + 1);
                    if (pick == 0) break;                       /* noop */
                    int p = EN_POS[pick - 1];
                    G[p] = EN_VAL[pick - 1];
                    if (legal(s, G)) break;
                    G[p] = NOOP[p];
                }
            }
        } else if (npool > 0) {   /* a uniform legal one, else noop */
            for (int k = 0; k < 8; k++) {
                const double *B = POOL + (size_t)(next64(rng) % (uint64_t)npool) * NA;
                if (legal(s, B)) { A = B; break; }
            }
        }
        double r = 0.0, d = 0.0;
        draws(rng, U, Z);
        step(s, A, U, Z, nx, &r, &d, l);
        total += disc * r; disc *= gamma; taken++;
        memcpy(s, nx, sizeof(double) * NS);
        if (d != 0) { ended = 1; break; }
    }
    *TAKEN = ended ? -taken : taken;
    return total;
}
