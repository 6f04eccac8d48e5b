"""ippc.rddl.sim: a vectorised RDDL simulator, `Model` -> numpy.

Theory of operation. Every pvariable is a tensor with one axis per
parameter (sized by its type's members) and a batch axis, so a whole batch
of states is stepped at once. Enum and object values are integer codes
(their index in the range type's members). Arrays go in and out batch
first, shaped (batch, *params); inside a step they are batch *last*,
(*params, batch), and the arrays a step returns are batch-first views of
batch-last memory: numpy's loops then run along the batch, which is what
makes large batches fast (reductions over a relation's small axes,
gathers of neighbours, are row operations).

The compiler turns the transition, and separately the action constraints,
into the source of one Python function of numpy operations, `exec`ed once:
a step is one call, with no Python loop over groundings and no walk of the
expression tree. An expression is compiled in a *scope* (the typed
variables free at that point: a cpf's parameters, then those of enclosing
aggregations), and its value is an array of rank len(scope) + 1: axis i the
i-th scope variable, the last axis the batch; any axis may have size 1
where the value does not depend on it, and broadcasting does the rest.
While it writes the function the compiler knows every value's shape and
dtype (it runs each operation once on stand-ins), and

* folds every subexpression that reads only non-fluents and constants into
  a constant, computed once when the simulator is built (a condition that
  is the same everywhere picks its branch);
* compiles an expression that does not draw in the smallest scope its
  variables need, and computes an expression that occurs twice once;
* turns `sum` and `exists` over a product or conjunction with a constant
  factor (CONNECTED(?y, ?x), NEIGHBOR(...)) into a matrix product, or a few
  row gathers where the relation pairs each value with few others; sums a
  variable that one factor alone depends on in that factor first; splits a
  sum of a sum or difference into two sums;
* checks a distribution's parameters when the simulator is built where they
  are constants, not at all where elementwise bounds carried through the
  arithmetic prove them valid, and otherwise with one comparison per
  parameter over the whole array.

The step is compiled for small batches (fewest numpy calls) and, on the
first large batch, again for large ones (least memory traffic: contiguous
layouts, gathers instead of products, logical operations instead of
np.where, results written in place, temporaries freed early). Both make
the same draws in the same order and compute the same values.

Random draws: one independent draw per batch element and per grounding of
every variable in scope, whatever the parameters depend on (Bernoulli and
Normal drawn batch last, (*scope, batch) in C order, as the step lays
values out; the others batch first, (batch, *scope)); nothing that draws
is ever folded or computed once for two draws, so the same seed gives the
same trajectory. The uniforms of every Bernoulli are drawn first, at once:
raw 64-bit outputs of the caller's bit generator, each cut into two 32-bit
integers u, one slot of them per draw site in the order of the expression
tree (left to right, inner first); Bernoulli(p) is u < p * 2**32, computed
exactly, so it fires with probability within 2**-32 of p (never for p = 0,
always for p = 1) at half the bits and none of the conversion of
`rng.random()`'s doubles, which cost more than the rest of the step on
large batches. A Bernoulli whose p is 0 everywhere (or 1 everywhere) when
the simulator is built draws nothing. The other distributions draw after
them, in the order of the tree, through the Generator's own methods. As
rddlsim, which evaluates only the branch taken, the branches of an `if`
or a `switch` (which each element takes one of) draw the same uniforms:
each element reads a uniform through one branch only, so one draw per
grounding is made where rddlsim makes one, yet the stream does not depend
on the branches taken; a condition that is the same everywhere draws for
its branch alone.

Semantics follow rddlsim: interm and derived fluents in level order (then
declaration order), then next-state cpfs, then observations (which may read
the next state); the reward of the transition sees the current state, the
actions, the intermediates and the next state; actions not given take their
default; `/` is real division; bools count as 0/1 in arithmetic; enum values
with integer names (@1) count as that integer in arithmetic;
action-preconditions and state-action-constraints are checked on the
current state and actions before the step, max-nondef-actions counts the
actions that differ from their default, and state-invariants are checked on
the next state. `termination` (pyRDDLGym) ends an episode when it holds.

The generated code, once. This two-computer SysAdmin (in `mini.rddl`;
`tests/rddl/test_sim_docstring.py` checks that the compiler writes exactly
what is shown here)

    domain mini {
        types { computer : object; };
        pvariables {
            CONNECTED(computer, computer) : { non-fluent, bool, default = false };
            running(computer) : { state-fluent, bool, default = true };
            reboot(computer) : { action-fluent, bool, default = false };
        };
        cpfs {
            running'(?c) = if (reboot(?c)) then true
                else Bernoulli(0.5 + 0.2 * sum_{?d : computer} [CONNECTED(?d, ?c) ^ running(?d)]);
        };
        reward = sum_{?c : computer} [running(?c) - reboot(?c)];
    }
    non-fluents mini_nf {
        domain = mini;
        objects { computer : {c1, c2}; };
        non-fluents { CONNECTED(c1, c2); CONNECTED(c2, c1); };
    }
    instance mini_1 {
        domain = mini;
        non-fluents = mini_nf;
        max-nondef-actions = 1;
        horizon = 10;
        discount = 1.0;
    }

steps batches of 2 to 15 states with this function (`Simulator.source()`):

    def _step(S, A, B, rng, check):
        a0 = A['reboot'].T
        s0 = S['running'].T
        if rng is None:
            _no_rng('mini.rddl:10:18: Bernoulli')
        _u = _uniforms(rng, 2 * B)
        u1 = _u[0 * B:2 * B].reshape((2, B))
        if check:
            if _cnz(a0) > 1:
                k2(A, B)
        t2 = _matmul(k9, s0.reshape(2, -1).astype(_f64, copy=False))
        t3 = _mul(k8, t2)
        t4 = _add(k6, t3)
        t5 = _mul(t4, k10)
        t6 = _lt(u1, t5)
        t7 = _lor(a0, t6)
        t8 = s0[0, :].astype(_i64) + s0[1, :]
        t9 = a0[0, :].astype(_i64) + a0[1, :]
        t10 = _sub(t8, t9)
        t11 = t10.astype(_f64)
        done = _zeros(B, _bool)
        return {'running': t7.T}, t11, None, done

`S` and `A` map fluent names to batch-first arrays, `B` is the batch size:
the inputs are read as batch-last views (`.T`); the uniforms of every
Bernoulli are drawn first, one slot each (`u1`: one per computer and
state); max-nondef-actions is checked over the whole batch, and `k2` (the
simulator's `_fail_nondef`) finds the state that breaks it. The sum over
`?d` of `CONNECTED(?d, ?c) ^ running(?d)` is a matrix product with the
constant CONNECTED (`k9`), 0.5 and 0.2 are the constants `k6` and `k8`,
and the Bernoulli is `u1 < p * 2**32` (`k10` = 2**32). The
`if` with a `true` branch is one `_lor`; the reward's sum over a short
axis adds its two slices. The `k`s are constants of the generated code's
namespace (`runtime._BUILTINS` names the rest), and the `t`s its
temporaries. Batches of 16 states or more step with `_step_large`, one
state with `_step_one`: the same draws and values, laid out for speed.

The package, one job per module (each module's docstring says what it owns
and what it may call):

    state          the public types: State, Step, Prepared, SimulationError
    simulator      Simulator: arrays, the step, the two-part step, wire names
    actions        random_actions and legal_actions
    build          writing the step and constraint functions from the model
    parts          what build and actions read of a Simulator (a protocol)
    order          the order of the cpfs
    compiler       _Compiler, assembled from the layers below
    base           values, statements, constant folding, `compile`
    operators      references, operators, if/switch, functions
    aggregations   sum_, exists_... and their contractions
    distributions  the random draws
    samplers       the draw functions of the other distributions
    bounds         interval bounds carried through the arithmetic
    code           the function being written, and its peephole passes
    runtime        the helpers the generated code calls
    prestep        the one-state step cut in its action-free and action parts
    scalar         the one-state step as one Python function over scalars
                   (`ScalarStep`, for tree search; its own draws)

`ippc.rddl.simulator` re-exports the public names.
"""

from __future__ import annotations

from .actions import RANDOM_MAX_CONCURRENT
from .simulator import Simulator
from .state import Prepared, SimulationError, State, Step

__all__ = ["RANDOM_MAX_CONCURRENT", "Prepared", "SimulationError", "Simulator", "State", "Step"]
