/* A stand-in for the generated part of a compiled step, for reading and
   checking the files of csrc/ alone (tests/rddl/test_cstep.py compiles each
   with -Wall -Wextra -Werror).

   The real unit is one text (rddl/sim/cstep.py's `c_source`): prelude.h, then
   `#define IPPC_STEP_UNIT`, the instance's sizes, its tables, `legal` and
   `step` as the translator writes them, then step_api.c and any caller's C
   (mcts's kernels.c and tree.c). With IPPC_STEP_UNIT defined, the files skip
   their `#include`s of this header. What the generated part provides:

   NS, NA   the number of state and action slots (doubles; at least 1)
   NU, NZ   the uniform and normal draws a step reads (at least 1)
   NL       the draw sites a step records (at least 1)
   HAS_LEGAL  1 when `legal` checks the model's constraints, else 0
   legal(S, A)  1 when action A is legal in state S
   step(S, A, U, Z, N, R, D, L)  the successor into N, the reward into *R,
            termination into *D (nonzero: the run ends), and at each draw
            site reached its probability (a normal: its deviation plus 2)
            into L[site]; sites not reached keep what the caller put there */
#ifndef IPPC_STEP_H
#define IPPC_STEP_H
#include "prelude.h"

#define NS 2
#define NA 1
#define NU 1
#define NZ 1
#define NL 2
#define HAS_LEGAL 1

static int legal(const double *S, const double *A) { return !(A[0] != 0 && S[0] != 0); }

static void step(const double *S, const double *A, const double *U, const double *Z,
                 double *N, double *R, double *D, double *L) {
    double p = A[0] != 0 ? 0.9 : 0.1, sd = 0.5;
    L[0] = p;
    N[0] = (double)(U[0] < p);
    L[1] = sd + 2.0;
    N[1] = S[1] + sd * Z[0];
    *R = S[0] - 0.25 * A[0];
    *D = 0.0;
}
#endif
