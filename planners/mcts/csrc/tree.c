/* THTS in C: the trials, expansions and backups of mcts's thts engine
   (planners/mcts/ctree.py says what it does and how Python drives it).

   Compiled in one unit after the instance's step, rddl/sim/csrc/step_api.c
   and kernels.c, whose probe, IDS, legal-action walk and roll-outs it calls. */
#ifndef IPPC_STEP_UNIT
#include "kernels.c"
#endif
#include <time.h>
typedef struct { long child; long count; double rsum, contrib; } t_out;
typedef struct { int act; long n; double h, tot, q; int det, solved; int nout, cap; t_out *outs; } t_act;
typedef struct { int steps; int done, expanded, solved; double value; int nacts; t_act *acts; long visits; uint64_t hash; } t_node;
typedef struct {
    int ncand; double *cands; int npool; double *pool; double noop[NA];
    cands_fn cb; long libn, libcap; double *lib;  /* state-dependent candidates */
    int scap;
    double U1[NU], Z1[NZ], U2[NU], Z2[NZ];
    double gamma, w, expl, hweight, bweight;
    int ids_depth, bellman, rollout_depth, policy, extrapolate, ids_deepen, enum_on, sunk, ids_smooth, blind_future; long max_nodes, token;
    uint64_t rng;
    t_node *nodes; double *states; long nn, capn;
    long *table; long tcap;
    long trials, leaves, ids_leaves, sim_steps, sinks_found;
    double *pn1, *pr1, *kept; int *pd1, *pdet, *psame, *pkeep; double *hv;
} tree;

static double now_s(void) { struct timespec ts; clock_gettime(CLOCK_MONOTONIC, &ts); return ts.tv_sec + 1e-9 * ts.tv_nsec; }

static void tree_clear(tree *t) {
    for (long i = 0; i < t->nn; i++) {
        t_node *nd = &t->nodes[i];
        for (int a = 0; a < nd->nacts; a++) free(nd->acts[a].outs);
        free(nd->acts);
    }
    t->nn = 0;
    if (t->table) memset(t->table, 0, sizeof(long) * (size_t)t->tcap);
}

void ctree_free(void *p) {
    tree *t = (tree *)p;
    if (!t) return;
    tree_clear(t);
    free(t->nodes); free(t->states); free(t->table); free(t->cands); free(t->pool); free(t->lib);
    free(t->pn1); free(t->pr1); free(t->kept); free(t->pd1); free(t->pdet); free(t->psame);
    free(t->pkeep); free(t->hv);
    free(t);
}

/* probe scratch for n candidates */
static int ensure_scratch(tree *t, int n) {
    if (n <= t->scap) return 0;
    int m = n * 2;
    free(t->pn1); free(t->pr1); free(t->kept); free(t->hv); free(t->pd1); free(t->pdet); free(t->psame); free(t->pkeep);
    t->pn1 = (double *)malloc(sizeof(double) * NS * (size_t)m);
    t->pr1 = (double *)malloc(sizeof(double) * (size_t)m);
    t->kept = (double *)malloc(sizeof(double) * NA * (size_t)m);
    t->hv = (double *)malloc(sizeof(double) * 2 * (size_t)m);  /* and the depth d-1 values */
    t->pd1 = (int *)malloc(sizeof(int) * (size_t)m); t->pdet = (int *)malloc(sizeof(int) * (size_t)m);
    t->psame = (int *)malloc(sizeof(int) * (size_t)m); t->pkeep = (int *)malloc(sizeof(int) * (size_t)m);
    t->scap = m;
    if (!t->pn1 || !t->pr1 || !t->kept || !t->hv || !t->pd1 || !t->pdet || !t->psame || !t->pkeep) { t->scap = 0; return -1; }
    return 0;
}

/* params: gamma, init_weight, exploration, heuristic_weight, blind_weight;
   iparams: ids_depth, bellman_outcomes, rollout_depth, policy (0 random, 1 noop, 2 best),
   extrapolate, max_nodes, token, ids_deepen, ids_smooth, blind_future */
void *ctree_new(const double *cands, int ncand, const double *pool, int npool, const double *noop,
                const double *probes, const double *params, const long *iparams, uint64_t seed,
                cands_fn cb) {
    tree *t = (tree *)calloc(1, sizeof(tree));
    if (!t) return 0;
    t->cb = cb;
    int m = ncand > 0 ? ncand : 1;
    t->ncand = ncand;
    t->cands = (double *)malloc(sizeof(double) * NA * (size_t)m);
    t->npool = npool;
    t->pool = (double *)malloc(sizeof(double) * NA * (size_t)(npool > 0 ? npool : 1));
    t->tcap = 1 << 12;
    t->table = (long *)calloc((size_t)t->tcap, sizeof(long));
    if (!t->cands || !t->pool || !t->table || ensure_scratch(t, m) < 0) { ctree_free(t); return 0; }
    if (ncand) memcpy(t->cands, cands, sizeof(double) * NA * (size_t)ncand);
    if (npool) memcpy(t->pool, pool, sizeof(double) * NA * (size_t)npool);
    memcpy(t->noop, noop, sizeof(double) * NA);
    memcpy(t->U1, probes, sizeof(double) * NU); memcpy(t->Z1, probes + NU, sizeof(double) * NZ);
    memcpy(t->U2, probes + NU + NZ, sizeof(double) * NU); memcpy(t->Z2, probes + 2 * NU + NZ, sizeof(double) * NZ);
    t->gamma = params[0]; t->w = params[1]; t->expl = params[2]; t->hweight = params[3]; t->bweight = params[4];
    t->ids_depth = (int)iparams[0]; t->bellman = (int)iparams[1]; t->rollout_depth = (int)iparams[2];
    t->policy = (int)iparams[3]; t->extrapolate = (int)iparams[4]; t->max_nodes = iparams[5];
    t->token = iparams[6]; t->ids_deepen = (int)iparams[7]; t->ids_smooth = (int)iparams[8];
    t->blind_future = (int)iparams[9];
    t->rng = seed;
    return t;
}

/* the action vector of an action id: a candidate's index, or (with a callback) its
   library row */
static const double *act_vec(tree *t, int act) { return (t->cb ? t->lib : t->cands) + (size_t)act * NA; }

static int lib_put(tree *t, int row, const double *vec) {
    if (row < 0) return -1;
    if (row >= t->libcap) {
        long cap = t->libcap ? t->libcap : 256;
        while (cap <= row) cap *= 2;
        double *lib = (double *)realloc(t->lib, sizeof(double) * NA * (size_t)cap);
        if (!lib) return -1;
        t->lib = lib; t->libcap = cap;
    }
    memcpy(t->lib + (size_t)row * NA, vec, sizeof(double) * NA);
    if (row >= t->libn) t->libn = row + 1;
    return 0;
}

void ctree_reset(void *p) { tree_clear((tree *)p); }
void ctree_set_ids(void *p, int depth) { ((tree *)p)->ids_depth = depth; }
/* IDS takes every state's candidates from `ippc_enum` instead of the callback */
void ctree_set_enum(void *p, int on) { ((tree *)p)->enum_on = on; }

static uint64_t node_hash(const double *S, int steps) {
    uint64_t h = hash_state(S, NS, 1469598103934665603ULL ^ ((uint64_t)(steps + 1) * 0x9E3779B97F4A7C15ULL));
    return h ? h : 1;
}

static int grow_table(tree *t) {
    long cap = t->tcap * 2;
    long *tab = (long *)calloc((size_t)cap, sizeof(long));
    if (!tab) return -1;
    for (long i = 0; i < t->nn; i++) {
        long j = (long)(t->nodes[i].hash & (uint64_t)(cap - 1));
        while (tab[j]) j = (j + 1) & (cap - 1);
        tab[j] = i + 1;
    }
    free(t->table); t->table = tab; t->tcap = cap;
    return 0;
}

/* the node of (S, steps), made when new; -1 when memory runs out */
static long get_node(tree *t, const double *S, int steps, int done) {
    uint64_t h = node_hash(S, steps);
    long j = (long)(h & (uint64_t)(t->tcap - 1));
    while (t->table[j]) {
        long i = t->table[j] - 1;
        t_node *nd = &t->nodes[i];
        if (nd->hash == h && nd->steps == steps && same(t->states + (size_t)i * NS, S, NS)) return i;
        j = (j + 1) & (t->tcap - 1);
    }
    if (t->nn == t->capn) {
        long cap = t->capn ? t->capn * 2 : 1024;
        t_node *nodes = (t_node *)realloc(t->nodes, sizeof(t_node) * (size_t)cap);
        if (!nodes) return -1;
        t->nodes = nodes;
        double *states = (double *)realloc(t->states, sizeof(double) * NS * (size_t)cap);
        if (!states) return -1;
        t->states = states; t->capn = cap;
    }
    long i = t->nn++;
    t_node *nd = &t->nodes[i];
    memset(nd, 0, sizeof *nd);
    nd->steps = steps; nd->done = done; nd->solved = done || steps <= 0; nd->hash = h;
    memcpy(t->states + (size_t)i * NS, S, sizeof(double) * NS);
    t->table[j] = i + 1;
    if (t->nn * 2 > t->tcap && grow_table(t) < 0) return -1;
    return i;
}

/* the discounted number of steps in n */
static double horizon_of(double g, int n) { return g == 1.0 ? (double)n : (1.0 - pow(g, n)) / (1.0 - g); }

static double extrapolated(double total, int taken, int steps, double g) {
    return total * horizon_of(g, steps) / horizon_of(g, taken);
}

static double walk1(tree *t, const double *S, int steps, int random_policy) {
    int n = t->rollout_depth == 0 ? steps : (t->rollout_depth < steps ? t->rollout_depth : steps);
    int taken = 0;
    double total = random_policy && t->npool == 0 && t->enum_on
        /* no pool of joint actions (too many), but the state's legal ones are walked in C */
        ? ippc_walk_enum(S, n, t->gamma, &t->rng, &taken)
        : ippc_walk(S, n, t->pool, random_policy ? t->npool : 0, t->noop, t->gamma, &t->rng, &taken);
    int ended = taken < 0;
    if (ended) taken = -taken;
    t->sim_steps += taken;
    if (!ended && taken < steps && taken > 0 && t->extrapolate) return extrapolated(total, taken, steps, t->gamma);
    return total;
}

static double rollout(tree *t, const double *S, int steps) {
    if (t->policy == 1) return walk1(t, S, steps, 0);
    if (t->policy == 0) return walk1(t, S, steps, 1);
    double a = walk1(t, S, steps, 0), b = walk1(t, S, steps, 1);
    return a > b ? a : b;
}

static int set_expanded(t_node *nd) {
    nd->expanded = 1;
    if (nd->nacts == 0) { nd->solved = 1; nd->value = 0.0; return 0; }
    double best = -INFINITY; int all = 1;
    for (int a = 0; a < nd->nacts; a++) {
        t_act *ac = &nd->acts[a];
        ac->q = ac->h;
        if (ac->h > best) best = ac->h;
        if (!ac->solved) all = 0;
    }
    nd->value = best;
    nd->solved = all;
    return 0;
}

static int expand(tree *t, long ni) {
    double S[NS + 1];
    memcpy(S, t->states + (size_t)ni * NS, sizeof(double) * NS);
    int steps = t->nodes[ni].steps;
    const double *cands = t->cands;
    int ncand = t->ncand;
    double *own = 0;
    int *own_idx = 0;
    if (t->cb) {
        ncand = cands_of(t->cb, S, &own, &own_idx);
        if (ncand < 0) return -1;
        for (int a = 0; a < ncand; a++) if (lib_put(t, own_idx[a], own + (size_t)a * NA) < 0) { free(own); free(own_idx); return -1; }
        cands = own;
    }
    if (ensure_scratch(t, ncand) < 0) { free(own); free(own_idx); return -1; }
    int kept = ippc_probe(S, cands, ncand, t->U1, t->Z1, t->U2, t->Z2,
                          t->pn1, t->pr1, t->pd1, t->pdet, t->psame, t->pkeep);
    if (kept < 0) { free(own); free(own_idx); return -1; }
    for (int a = 0; a < ncand; a++) t->sim_steps += t->pdet[a] ? 1 : 2;
    t_act *acts = (t_act *)calloc((size_t)(kept > 0 ? kept : 1), sizeof(t_act));
    if (!acts) { free(own); free(own_idx); return -1; }
    int k = 0;
    for (int a = 0; a < ncand; a++) {
        if (!t->pkeep[a]) continue;
        acts[k].act = own_idx ? own_idx[a] : a; acts[k].det = t->pdet[a];
        memcpy(t->kept + (size_t)k * NA, cands + (size_t)a * NA, sizeof(double) * NA);
        k++;
    }
    free(own); free(own_idx);
    t_node *nd = &t->nodes[ni];
    nd->acts = acts; nd->nacts = kept;
    t->leaves++;
    if (kept > 0) {
        /* a sink: every kept action is deterministic and leaves S as it is, so no action
           ever changes the state again: each action's value is exact (its reward, then the
           best reward every step after) */
        int sink = 1; double best = -INFINITY;
        for (int a = 0; a < ncand && sink; a++) {
            if (!t->pkeep[a]) continue;
            if (!t->pdet[a] || t->pd1[a] || !same(t->pn1 + (size_t)a * NS, S, NS)) sink = 0;
            else if (t->pr1[a] > best) best = t->pr1[a];
        }
        if (sink) {
            double rest = steps <= 1 ? 0.0 : best * horizon_of(t->gamma, steps - 1);
            for (int k2 = 0, a = -1; k2 < kept; k2++) {
                do a++; while (!t->pkeep[a]);
                acts[k2].h = t->pr1[a] + t->gamma * rest; acts[k2].solved = 1;
            }
            t->sinks_found++; t->sunk = 1;
            return set_expanded(nd);
        }
    }
    if (t->ids_depth && steps > 1 && kept > 0) {
        int d = t->ids_depth < steps ? t->ids_depth : steps;
        /* PROST's IDS: deepen from 2 and stop at the first depth where an action beats
           noop (when noop is a kept action), else at the depth learned */
        int noop_k = -1;
        if (t->ids_deepen && d > 2)
            for (int a = 0; a < kept && noop_k < 0; a++)
                if (same(t->kept + (size_t)a * NA, t->noop, NA)) noop_k = a;
        IDS_CB = t->enum_on ? enum_cb : t->cb;
        for (int upto = d, dd = noop_k >= 0 ? 2 : d; ; dd++) {
            d = dd;
            t->sim_steps += ippc_ids_values(S, t->kept, kept, t->cands, t->ncand, d, t->gamma, t->hv, t->token);
            if (d >= upto) break;
            int better = 0;
            for (int a = 0; a < kept && !better; a++) if (a != noop_k && t->hv[a] > t->hv[noop_k]) better = 1;
            if (better) break;
        }
        /* with blind_future, roll-outs too where every action but noop costs more now
           than noop and the values differ only by that first step's reward: whatever
           follows it is worth the same after every action (within its depth IDS sees
           no goal, only what each action costs now), and these values would only
           rank noop first */
        int future_alike = 0;
        int noop_at = -1;
        if (t->blind_future && d >= 2 && kept > 1)
            for (int a = 0; a < kept && noop_at < 0; a++)
                if (same(t->kept + (size_t)a * NA, t->noop, NA)) noop_at = a;
        if (noop_at >= 0) {
            double *h1 = t->hv + t->scap;
            t->sim_steps += ippc_ids_values(S, t->kept, kept, t->cands, t->ncand, 1, t->gamma, h1, t->token);
            double f0 = t->hv[noop_at] - h1[noop_at];
            double tol = 1e-9 * (1.0 + (f0 < 0 ? -f0 : f0));
            future_alike = 1;
            for (int a = 0; a < kept && future_alike; a++) {
                if (a == noop_at) continue;
                double f = t->hv[a] - h1[a];
                if (f - f0 > tol || f0 - f > tol || h1[a] >= h1[noop_at] - tol) future_alike = 0;
            }
        }
        if (t->ids_smooth && d >= 3) {
            /* the mean of the depth-d and depth-(d-1) values a step: an estimate that does
               not swing with the parity of the depth (a reward every other step); not at
               depth 2, whose partner would be the immediate reward alone */
            double *h2 = t->hv + t->scap;
            t->sim_steps += ippc_ids_values(S, t->kept, kept, t->cands, t->ncand, d - 1, t->gamma, h2, t->token);
            for (int a = 0; a < kept; a++)
                t->hv[a] = 0.5 * (t->hv[a] + (t->gamma == 1.0 ? h2[a] * d / (d - 1.0) : h2[a]));
        }
        IDS_CB = 0;
        double lo = t->hv[0], hi = t->hv[0];
        for (int a = 1; a < kept; a++) { if (t->hv[a] < lo) lo = t->hv[a]; if (t->hv[a] > hi) hi = t->hv[a]; }
        /* where IDS values every action alike, roll-outs stand in; but once the session
           has met a sink, these values themselves times blind_weight (< 1 keeps such a
           blind estimate above the exact value of a sink it may avoid) */
        int alike = lo == hi && kept > 1;
        if (alike) future_alike = 0;
        if (!future_alike && (!alike || (t->sunk && t->bweight > 0))) {
            double scale = (alike ? t->bweight : t->hweight) * (t->gamma == 1.0 ? (double)steps / d : 1.0);
            for (int a = 0; a < kept; a++) { acts[a].h = t->hv[a] * scale; acts[a].solved = 0; }
            t->ids_leaves++;
            return set_expanded(nd);
        }
    }
    double nx[NS + 1], U[NU + 1], Z[NZ + 1], l[NL + 1];
    for (int k2 = 0, a = -1; k2 < kept; k2++) {
        t_act *ac = &acts[k2];
        do a++; while (!t->pkeep[a]);    /* its probe's index */
        double r1 = t->pr1[a];
        int d1 = t->pd1[a];
        if (steps == 1 || (ac->det && d1)) { ac->h = r1; ac->solved = ac->det ? 1 : t->psame[a]; continue; }
        const double *succ; double r; int done;
        if (ac->det) { succ = t->pn1 + (size_t)a * NS; r = r1; done = d1; }
        else {
            double D = 0.0; r = 0.0;
            draws(&t->rng, U, Z);
            step(S, t->kept + (size_t)k2 * NA, U, Z, nx, &r, &D, l);
            t->sim_steps++;
            succ = nx; done = D != 0;
        }
        double value = done ? 0.0 : rollout(t, succ, steps - 1);
        ac->h = r + t->gamma * value;
        ac->solved = 0;
    }
    return set_expanded(nd);
}

static double out_total(tree *t, t_act *ac) {
    double tot = 0.0;
    for (int o = 0; o < ac->nout; o++) {
        t_out *ou = &ac->outs[o];
        double c = ou->rsum + t->gamma * ou->count * t->nodes[ou->child].value;
        ou->contrib = c; tot += c;
    }
    return tot;
}

static void update(tree *t, t_node *nd, int a, t_out *ou) {
    t_act *ac = &nd->acts[a];
    if (ac->det && ou && t->nodes[ou->child].solved) {
        ac->solved = 1;
        ac->q = ou->rsum / ou->count + t->gamma * t->nodes[ou->child].value;
    } else if (!ac->solved) {
        ac->q = (t->w * ac->h + ac->tot) / (t->w + ac->n);
    }
    double best = -INFINITY; int all = 1;
    for (int b = 0; b < nd->nacts; b++) { if (nd->acts[b].q > best) best = nd->acts[b].q; if (!nd->acts[b].solved) all = 0; }
    nd->value = best;
    if (ac->solved && all) nd->solved = 1;
}

static int select_act(tree *t, t_node *nd) {
    double hi = -INFINITY, lo = INFINITY;
    for (int a = 0; a < nd->nacts; a++) { double q = nd->acts[a].q; if (q > hi) hi = q; if (q < lo) lo = q; }
    double scale = fabs(hi) > fabs(lo) ? fabs(hi) : fabs(lo);
    if (scale == 0) scale = 1.0;
    double c = t->expl * scale, logn = log(nd->visits + t->w * nd->nacts + 1.0), best = -INFINITY;
    int pick = -1, ties = 0;
    for (int a = 0; a < nd->nacts; a++) {
        t_act *ac = &nd->acts[a];
        if (ac->solved) continue;
        double v = ac->q + c * sqrt(logn / (t->w + ac->n));
        if (v > best) { best = v; pick = a; ties = 1; }
        else if (v == best) { ties++; if (unif(&t->rng) * ties < 1.0) pick = a; }
    }
    return pick;
}

#define PATHMAX 4096
static int trial(tree *t, long root) {
    long pn[PATHMAX]; int pa[PATHMAX], po[PATHMAX], depth = 0;
    long ni = root;
    double nx[NS + 1], U[NU + 1], Z[NZ + 1], l[NL + 1];
    while (!t->nodes[ni].solved && depth < PATHMAX) {
        if (!t->nodes[ni].expanded) { if (expand(t, ni) < 0) return -1; break; }
        t_node *nd = &t->nodes[ni];
        int a = select_act(t, nd);
        if (a < 0) break;
        double r = 0.0, D = 0.0;
        draws(&t->rng, U, Z);
        step(t->states + (size_t)ni * NS, act_vec(t, nd->acts[a].act), U, Z, nx, &r, &D, l);
        t->sim_steps++;
        int steps = nd->steps;
        long child = get_node(t, nx, steps - 1, D != 0);
        if (child < 0) return -1;
        t_act *ac = &t->nodes[ni].acts[a];
        int o = 0;
        while (o < ac->nout && ac->outs[o].child != child) o++;
        if (o == ac->nout) {
            if (ac->nout == ac->cap) {
                int cap = ac->cap ? ac->cap * 2 : 2;
                t_out *outs = (t_out *)realloc(ac->outs, sizeof(t_out) * (size_t)cap);
                if (!outs) return -1;
                ac->outs = outs; ac->cap = cap;
            }
            ac->outs[o].child = child; ac->outs[o].count = 0; ac->outs[o].rsum = 0.0; ac->outs[o].contrib = 0.0;
            ac->nout++;
        }
        ac->outs[o].count++; ac->outs[o].rsum += r;
        pn[depth] = ni; pa[depth] = a; po[depth] = o; depth++;
        ni = child;
    }
    for (int k = depth - 1; k >= 0; k--) {
        t_node *nd = &t->nodes[pn[k]];
        t_act *ac = &nd->acts[pa[k]];
        t_out *ou = &ac->outs[po[k]];
        ac->n++; nd->visits++;
        if (ac->nout <= t->bellman) ac->tot = out_total(t, ac);
        else {
            double c = ou->rsum + t->gamma * ou->count * t->nodes[ou->child].value;
            ac->tot += c - ou->contrib; ou->contrib = c;
        }
        update(t, nd, pa[k], ou);
    }
    return 0;
}

static void refresh(tree *t, long ni) {
    t_node *nd = &t->nodes[ni];
    for (int a = 0; a < nd->nacts; a++) {
        t_act *ac = &nd->acts[a];
        if (ac->solved || !ac->nout) continue;
        ac->tot = out_total(t, ac);
        update(t, nd, a, ac->det ? &ac->outs[0] : 0);
    }
}

/* The root node of (S, steps); the tree is forgotten first when it holds more than
   max_nodes nodes. -1: out of memory. */
long ctree_root(void *p, const double *S, int steps) {
    tree *t = (tree *)p;
    if (t->nn > t->max_nodes) tree_clear(t);
    return get_node(t, S, steps, 0);
}

/* Trials from `root` for `budget` seconds (less the slowest recent trial), or exactly
   `iterations` (>= 0); the root is expanded first whatever the time. STATS: trials,
   leaves, ids_leaves, sim_steps, sinks of this call. Returns 0, or -1 when memory ran out. */
int ctree_search(void *p, long root, double budget, long iterations, long *STATS) {
    tree *t = (tree *)p;
    t->trials = t->leaves = t->ids_leaves = t->sim_steps = t->sinks_found = 0;
    int rc = 0;
    double end = now_s() + budget;
    if (!t->nodes[root].expanded && !t->nodes[root].solved) rc = expand(t, root);
    double piece = 0.0;
    long done = 0;
    while (rc == 0 && !t->nodes[root].solved) {
        if (iterations >= 0) { if (done >= iterations) break; }
        else if (now_s() + piece >= end) break;
        double t0 = now_s();
        rc = trial(t, root);
        done++;
        double took = now_s() - t0;
        piece = took > 0.8 * piece ? took : 0.8 * piece;
    }
    if (rc == 0) refresh(t, root);
    STATS[0] = done; STATS[1] = t->leaves; STATS[2] = t->ids_leaves; STATS[3] = t->sim_steps; STATS[4] = t->sinks_found;
    return rc;
}

/* A node's actions: candidate indices, values, samples, solved labels; FLAGS: expanded, solved, steps,
   node count. Returns the number of actions; VALUE its value. */
int ctree_info(void *p, long ni, int cap, int *ACTS, double *Q, long *N, int *SOLVED, double *VALUE,
               long *FLAGS) {
    tree *t = (tree *)p;
    t_node *nd = &t->nodes[ni];
    for (int a = 0; a < nd->nacts && a < cap; a++) {
        ACTS[a] = nd->acts[a].act; Q[a] = nd->acts[a].q; N[a] = nd->acts[a].n; SOLVED[a] = nd->acts[a].solved;
    }
    *VALUE = nd->value;
    FLAGS[0] = nd->expanded; FLAGS[1] = nd->solved; FLAGS[2] = nd->steps; FLAGS[3] = t->nn;
    return nd->nacts;
}
