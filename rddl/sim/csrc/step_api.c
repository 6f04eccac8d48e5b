/* The compiled step's entry points and its random generator (rddl/sim/cstep.py).

   Compiled in one unit after the instance's generated step, which defines
   NS, NA, NU, NZ (state, action, uniform and normal draw counts), NL (the
   recorded draw sites), HAS_LEGAL, and the functions `step` and `legal`
   (step.h stands in for them when this file is read alone). Every draw comes from
   a splitmix64 generator whose state the caller owns: a seed gives the same
   draws on any machine. */
#ifndef IPPC_STEP_UNIT
#include "step.h"
#endif

static uint64_t next64(uint64_t *s) {
    uint64_t z = (*s += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
}
static double unif(uint64_t *s) { return (double)(next64(s) >> 11) * 0x1.0p-53; }
static void draws(uint64_t *s, double *U, double *Z) {
    for (int i = 0; i < NU; i++) U[i] = unif(s);
    for (int i = 0; i < NZ; i += 2) {
        double u1 = unif(s), u2 = unif(s);
        double r = sqrt(-2.0 * log(1.0 - u1));
        Z[i] = r * cos(6.283185307179586 * u2);
        if (i + 1 < NZ) Z[i + 1] = r * sin(6.283185307179586 * u2);
    }
}

/* whether the preconditions and state-action constraints hold (1 where the
   model has none, or they could not be written) */
int ippc_legal(const double *S, const double *A) { return legal(S, A); }

int ippc_sizes(int *out) { out[0] = NS; out[1] = NA; out[2] = NU; out[3] = NZ; out[4] = NL; return 0; }

/* one step with given draws; L: NL recorded slots */
int ippc_step(const double *S, const double *A, const double *U, const double *Z,
              double *N, double *R, double *L) {
    double D = 0.0, l[NL + 1];
    if (!L) L = l;
    step(S, A, U, Z, N, R, &D, L);
    return D != 0;
}

/* one sampled step */
int ippc_sample(const double *S, const double *A, uint64_t *rng, double *N, double *R) {
    double U[NU + 1], Z[NZ + 1], l[NL + 1], D = 0.0;
    draws(rng, U, Z);
    step(S, A, U, Z, N, R, &D, l);
    return D != 0;
}

/* whether `legal` checks the model's constraints (0: they could not be written) */
int ippc_has_legal(void) { return HAS_LEGAL; }
