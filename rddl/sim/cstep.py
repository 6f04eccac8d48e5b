"""The one-state step compiled to C, with the search's inner loops beside it.

`ScalarStep` writes an instance's transition as one Python function over
scalars; a step costs some microseconds of interpreted Python, and a tree
search makes tens of them for each node it expands (probing every action,
roll-outs, IDS on the determinisation). `CStep` translates that function,
node by node of its Python syntax tree, into C over doubles, compiles it
with the system's C compiler (`$CC`, else `cc`, `gcc` or `clang`) into a
shared library, and loads it with ctypes. The loops that call the step many
times run in C too, so that one call from Python does a whole piece of
work:

* `probe`: every candidate action of a state under two fixed draw vectors,
  recording the probability at every Bernoulli and Discrete site and the
  standard deviation at every Normal site (the deterministic / equivalent
  action test of `planners.mcts.thts`);
* `ids_values`: PROST's IDS on the most-likely determinisation (every
  uniform 0.5, every normal 0) to a depth, with a cache of (depth, state)
  values kept across calls;
* `walk`: a roll-out of noop or uniformly drawn actions from a pool;
* `sample`: one sampled transition.

Every value is a double in C: booleans are 0/1, integers and enum or object
codes exact up to 2**53. The translation keeps Python's semantics where
they matter to a step: `and`/`or` return an operand and short-circuit (a
draw site not reached is not recorded, as in the Python probe), `x if c
else y`, chained comparisons, the helpers' conventions (`_div`, `_ln`,
`_sqrt`, `_pow`, numpy's round half to even). Where Python raises (a float
division by zero in a constant, `math.acos(2)`), C gives inf or nan.
Anything else in the source (a construct the translator does not know)
raises `CUnavailable`, as does a missing or failing compiler: the caller
keeps the Python step. The draws come from a splitmix64 generator in C,
seeded by the caller, so a seed still gives the same search.

Compiled libraries are cached by the hash of their C source in
`$IPPC_CACHE/cstep` (default `~/.cache/ippc/cstep`, else a temporary
folder), so a second session on an instance loads in milliseconds.

Imports only `scalar` (whose source and tables it translates).
"""

from __future__ import annotations

import ast
import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path
from typing import Any

import numpy as np

from .scalar import ScalarStep

__all__ = ["CStep", "CUnavailable", "find_compiler"]

StateT = tuple[Any, ...]


class CUnavailable(Exception):
    """No C step for this instance: no compiler, a failed build, or a
    construct the translator does not write."""


def find_compiler() -> str | None:
    """The C compiler to use: `$CC`, else the first of cc, gcc, clang."""
    env = os.environ.get("CC")
    if env:
        return shutil.which(env.split()[0]) and env  # type: ignore[return-value]
    for name in ("cc", "gcc", "clang"):
        if shutil.which(name):
            return name
    return None


# Python's helpers, in C (`scalar._HELPERS`); double in, double out
_C_HELPERS = {
    "_div": "py_div", "_ln": "py_ln", "_sqrt": "py_sqrt", "_pow": "py_pow",
    "_sgn": "py_sgn", "_round": "nearbyint", "_exp": "exp", "_floor": "floor",
    "_ceil": "ceil", "_cos": "cos", "_sin": "sin", "_tan": "tan", "_acos": "acos",
    "_asin": "asin", "_atan": "atan", "_cosh": "cosh", "_sinh": "sinh", "_tanh": "tanh",
    "abs": "fabs",
}  # fmt: skip

_CMP = {
    ast.Eq: "==", ast.NotEq: "!=", ast.Lt: "<", ast.LtE: "<=", ast.Gt: ">", ast.GtE: ">=",
}  # fmt: skip
_ARITH = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/"}

_PRELUDE = r"""
#include <math.h>
#include <stdint.h>
#include <string.h>
#include <stdlib.h>
static double py_div(double x, double y) {
    if (y == 0) { if (x == 0 || x != x) return NAN; return copysign(INFINITY, x) * copysign(1.0, y); }
    return x / y;
}
static double py_ln(double x) { return x > 0 ? log(x) : (x == 0 ? -INFINITY : NAN); }
static double py_sqrt(double x) { return x >= 0 ? sqrt(x) : NAN; }
static double py_pow(double x, double y) { return pow(x, y); }
static double py_sgn(double x) { return (double)((x > 0) - (x < 0)); }
/* Python's float // (its divmod: 1.0 // 0.1 is 9.0, not floor(10.000000000000002)) */
static double py_floordiv(double x, double y) {
    if (y == 0) return floor(py_div(x, y));
    double mod = fmod(x, y), div = (x - mod) / y;
    if (mod != 0 && ((y < 0) != (mod < 0))) div -= 1.0;
    if (div == 0) return copysign(0.0, x / y);
    double fl = floor(div);
    if (div - fl > 0.5) fl += 1.0;
    return fl;
}
static double py_mod(double x, double y) { double m = fmod(x, y); if (m != 0 && ((m < 0) != (y < 0))) m += y; return m; }
static double py_discrete(double u, const double *p, int n) {
    double acc = 0.0;
    for (int i = 0; i < n; i++) { acc += p[i]; if (u < acc) return (double)i; }
    return (double)(n - 1);
}
"""


class _Translator:
    """Python source of `ScalarStep` -> the body of a C function."""

    def __init__(self, scalar: ScalarStep):
        self.scalar = scalar
        self.tables: dict[str, str] = {}  # Python table text -> C array name
        self.table_defs: list[str] = []
        self.slots = 0  # recorded draw sites
        self.temps = 0
        self.locals: set[str] = set()
        self.boolean: set[str] = set()  # locals known to hold 0/1

    def fail(self, node: ast.AST, why: str = "") -> CUnavailable:
        return CUnavailable(f"cannot translate {ast.unparse(node)[:80]!r} {why}".strip())

    def tmp(self) -> str:
        self.temps += 1
        return f"_t{self.temps}"

    def table(self, values: list[Any], node: ast.AST) -> str:
        key = repr(values)
        name = self.tables.get(key)
        if name is None:
            name = self.tables[key] = f"T{len(self.tables)}"
            items = ", ".join(self.const(v, node) for v in values) or "0"
            self.table_defs.append(f"static const double {name}[] = {{{items}}};")
        return name

    def const(self, v: Any, node: ast.AST) -> str:
        if isinstance(v, bool):
            return "1.0" if v else "0.0"
        if isinstance(v, int):
            if abs(v) > 2**53:
                raise self.fail(node, "(an integer beyond 2**53)")
            return f"{v}.0"
        if isinstance(v, float):
            if v != v:
                return "NAN"
            if v in (float("inf"), float("-inf")):
                return "INFINITY" if v > 0 else "(-INFINITY)"
            return repr(v)
        raise self.fail(node, "(a constant)")

    def is_bool(self, n: ast.expr) -> bool:
        if isinstance(n, ast.Compare):
            return True
        if isinstance(n, ast.UnaryOp) and isinstance(n.op, ast.Not):
            return True
        if isinstance(n, ast.Constant):
            return isinstance(n.value, bool)
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id == "bool":
            return True
        if isinstance(n, ast.BoolOp):
            return all(self.is_bool(v) for v in n.values)
        if isinstance(n, ast.IfExp):
            return self.is_bool(n.body) and self.is_bool(n.orelse)
        if isinstance(n, ast.Name):
            return n.id in self.boolean
        return False

    @staticmethod
    def draw(n: ast.expr) -> tuple[str, int] | None:
        """('U' or 'Z', index) for a draw `U[k]` / `Z[k]`."""
        if (
            isinstance(n, ast.Subscript)
            and isinstance(n.value, ast.Name)
            and n.value.id in ("U", "Z")
            and isinstance(n.slice, ast.Constant)
            and isinstance(n.slice.value, int)
        ):
            return n.value.id, n.slice.value
        return None

    def record(self, value: str, offset: str = "") -> tuple[str, str]:
        """A statement expression's start recording `value` in a new slot."""
        slot = self.slots
        self.slots += 1
        t = self.tmp()
        return t, f"double {t} = ({value}); L[{slot}] = {t}{offset};"

    def ex(self, n: ast.expr) -> str:  # noqa: C901, PLR0911, PLR0912 - one case per node type
        if isinstance(n, ast.Constant):
            return self.const(n.value, n)
        if isinstance(n, ast.Name):
            i = n.id
            if i in ("True", "False"):
                return "1.0" if i == "True" else "0.0"
            if i == "_inf":
                return "INFINITY"
            if i == "_nan":
                return "NAN"
            if i[0] in "sa" and i[1:].isdigit():
                return f"{'S' if i[0] == 's' else 'A'}[{i[1:]}]"
            if i in self.locals:
                return i
            raise self.fail(n, "(an unknown name)")
        if isinstance(n, ast.BoolOp):
            vals = [self.ex(v) for v in n.values]
            if all(self.is_bool(v) for v in n.values):
                op = " && " if isinstance(n.op, ast.And) else " || "
                return "(double)(" + op.join(f"({v}) != 0" for v in vals) + ")"
            out = vals[-1]
            for v in reversed(vals[:-1]):
                t = self.tmp()
                if isinstance(n.op, ast.And):
                    out = f"({{ double {t} = ({v}); {t} != 0 ? ({out}) : {t}; }})"
                else:
                    out = f"({{ double {t} = ({v}); {t} != 0 ? {t} : ({out}); }})"
            return out
        if isinstance(n, ast.UnaryOp):
            x = self.ex(n.operand)
            if isinstance(n.op, ast.Not):
                return f"(double)(({x}) == 0)"
            if isinstance(n.op, ast.USub):
                return f"(-({x}))"
            if isinstance(n.op, ast.UAdd):
                return x
            raise self.fail(n)
        if isinstance(n, ast.IfExp):
            return f"(({self.ex(n.test)}) != 0 ? ({self.ex(n.body)}) : ({self.ex(n.orelse)}))"
        if isinstance(n, ast.BinOp):
            return self.binop(n)
        if isinstance(n, ast.Compare):
            return self.compare(n)
        if isinstance(n, ast.Subscript):
            return self.subscript(n)
        if isinstance(n, ast.Call):
            return self.call(n)
        raise self.fail(n)

    def binop(self, n: ast.BinOp) -> str:
        if isinstance(n.op, ast.Mult):
            for draw, other in ((n.right, n.left), (n.left, n.right)):
                d = self.draw(draw)
                if d is not None and d[0] == "Z":
                    t, start = self.record(self.ex(other), " + 2.0")
                    return f"({{ {start} {t} * Z[{d[1]}]; }})"
        if self.draw(n.left) or self.draw(n.right):
            raise self.fail(n, "(a draw in arithmetic)")
        a, b = self.ex(n.left), self.ex(n.right)
        op = _ARITH.get(type(n.op))
        if op is not None:
            return f"(({a}) {op} ({b}))"
        if isinstance(n.op, ast.FloorDiv):
            return f"py_floordiv({a}, {b})"
        if isinstance(n.op, ast.Mod):
            return f"py_mod({a}, {b})"
        if isinstance(n.op, ast.Pow):
            return f"py_pow({a}, {b})"
        raise self.fail(n)

    def compare(self, n: ast.Compare) -> str:
        if len(n.ops) == 1:
            op = _CMP.get(type(n.ops[0]))
            if op is None:
                raise self.fail(n)
            left, right = n.left, n.comparators[0]
            dl, dr = self.draw(left), self.draw(right)
            if dl and dl[0] == "U" and op == "<" and not dr:  # U[k] < p
                t, start = self.record(self.ex(right))
                return f"({{ {start} (double)(U[{dl[1]}] < {t}); }})"
            if dr and dr[0] == "U" and op == ">" and not dl:  # p > U[k]
                t, start = self.record(self.ex(left))
                return f"({{ {start} (double)({t} > U[{dr[1]}]); }})"
            if dl or dr:
                raise self.fail(n, "(a draw compared)")
            return f"(double)(({self.ex(left)}) {op} ({self.ex(right)}))"
        # a < b < c: each operand once, stopping at the first false
        operands = [n.left, *n.comparators]
        if any(self.draw(o) for o in operands):
            raise self.fail(n, "(a draw compared)")
        names = [self.tmp() for _ in operands]
        parts = [f"double {names[0]} = ({self.ex(operands[0])});", "double _r = 1.0;"]
        body = ""
        for k, op_node in enumerate(n.ops):
            op = _CMP.get(type(op_node))
            if op is None:
                raise self.fail(n)
            body += (
                f" if (_r) {{ double {names[k + 1]} = ({self.ex(operands[k + 1])});"
                f" _r = ({names[k]} {op} {names[k + 1]}); "
            )
        body += "}" * len(n.ops)
        return f"({{ {' '.join(parts)}{body} _r; }})"

    def subscript(self, n: ast.Subscript) -> str:
        if self.draw(n):
            raise self.fail(n, "(a draw read directly)")
        index = self.ex(n.slice)
        v = n.value
        if isinstance(v, ast.Tuple) and all(isinstance(e, ast.Constant) for e in v.elts):
            name = self.table([e.value for e in v.elts], n)  # type: ignore[attr-defined]
        elif isinstance(v, ast.Name) and v.id in self.scalar.tables:
            name = self.table(list(self.scalar.tables[v.id]), n)
        else:
            raise self.fail(n)
        return f"{name}[(long)({index})]"

    def call(self, n: ast.Call) -> str:
        if not isinstance(n.func, ast.Name) or n.keywords:
            raise self.fail(n)
        f = n.func.id
        args = n.args
        if f == "_discrete" and len(args) == 2 and isinstance(args[1], ast.Tuple):
            d = self.draw(args[0])
            if d is None or d[0] != "U":
                raise self.fail(n)
            probs = [self.ex(p) for p in args[1].elts]
            k = len(probs)
            slot = self.slots
            self.slots += k
            t = self.tmp()
            fill = " ".join(f"L[{slot + i}] = {t}[{i}];" for i in range(k))
            return (
                f"({{ double {t}[{k}] = {{{', '.join(probs)}}}; {fill}"
                f" py_discrete(U[{d[1]}], {t}, {k}); }})"
            )
        if any(self.draw(a) for a in args):
            raise self.fail(n, "(a draw passed on)")
        xs = [self.ex(a) for a in args]
        if f == "bool" and len(xs) == 1:
            return f"(double)(({xs[0]}) != 0)"
        if f == "float" and len(xs) == 1:
            return f"({xs[0]})"
        if f == "int" and len(xs) == 1:
            return f"trunc({xs[0]})"
        if f in ("min", "max") and len(xs) >= 2:
            # Python's: the first of the smallest (largest)
            out = xs[0]
            for x in xs[1:]:
                a, b = self.tmp(), self.tmp()
                cmp = "<" if f == "min" else ">"
                out = (
                    f"({{ double {a} = ({out}); double {b} = ({x}); {b} {cmp} {a} ? {b} : {a}; }})"
                )
            return out
        c = _C_HELPERS.get(f)
        if c is not None and len(xs) == (2 if f in ("_div", "_pow") else 1):
            return f"{c}({', '.join(xs)})"
        raise self.fail(n)

    def function(self, source: str | None = None) -> str:
        """The body of the step (or of `legal`, given its source)."""
        tree = ast.parse(source if source is not None else self.scalar.source)
        fn = tree.body[0]
        if not isinstance(fn, ast.FunctionDef):
            raise CUnavailable("unexpected source")
        self.locals = set()
        self.boolean = set()
        lines: list[str] = []
        for st in fn.body:
            if isinstance(st, ast.Assign) and len(st.targets) == 1:
                target = st.targets[0]
                if isinstance(target, ast.Tuple):  # (s0, s1, ...) = S
                    continue
                if not isinstance(target, ast.Name):
                    raise self.fail(st)
                name = target.id
                if name in ("U", "Z"):  # the draw blocks: given
                    continue
                value = self.ex(st.value)
                if self.is_bool(st.value):
                    self.boolean.add(name)
                if name == "r":
                    lines.append(f"    *R = {value};")
                elif name == "done":
                    lines.append(f"    *D = {value};")
                else:
                    self.locals.add(name)
                    lines.append(f"    double {name} = {value};")
                continue
            if isinstance(st, ast.Return) and isinstance(st.value, ast.Tuple):
                nxt = st.value.elts[0]
                if not isinstance(nxt, ast.Tuple):
                    raise self.fail(st)
                for j, e in enumerate(nxt.elts):
                    lines.append(f"    N[{j}] = {self.ex(e)};")
                continue
            if isinstance(st, ast.Return) and st.value is not None and source is not None:
                lines.append(f"    return ({self.ex(st.value)}) != 0;")
                continue
            raise self.fail(st)
        return "\n".join(lines)


_KERNELS = r"""
/* ---- the search's loops (fixed text) ---- */
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
   KEEP 1 for the first of each class of equivalent actions, else 0. */
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
        for (int b = 0; b < a && !dup; b++)
            if (KEEP[b] && hs[b] == h && same(sig + (size_t)b * W, g, W)) dup = 1;
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

int ippc_has_legal(void) { return HAS_LEGAL; }

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
"""


def _cache_dir() -> Path:
    root = os.environ.get("IPPC_CACHE")
    base = Path(root) if root else Path.home() / ".cache" / "ippc"
    folder = base / "cstep"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".w{os.getpid()}"
        probe.write_text("")
        probe.unlink()
        return folder
    except OSError:
        folder = Path(tempfile.gettempdir()) / f"ippc-cstep-{os.getuid()}"
        folder.mkdir(parents=True, exist_ok=True)
        return folder


def c_source(scalar: ScalarStep, extra: str = "") -> str:
    """The C text of `scalar`'s step and the kernels, then `extra` (C text
    that may call them; raises `CUnavailable`)."""
    tr = _Translator(scalar)
    body = tr.function()
    slots = tr.slots
    legal = "    (void)S; (void)A; return 1;"
    has_legal = 0
    if scalar.legal_source is not None:
        try:
            legal = "    (void)S; (void)A;\n" + tr.function(scalar.legal_source)
            has_legal = 1
        except CUnavailable:
            pass  # (roll-outs then draw without the check, as the Python step's do)
    ns, na = len(scalar.state_keys), len(scalar.action_keys)
    head = [
        _PRELUDE,
        f"#define NS {max(ns, 1)}",
        f"#define NA {max(na, 1)}",
        f"#define NU {max(scalar.n_uniforms, 1)}",
        f"#define NZ {max(scalar.n_normals, 1)}",
        f"#define NL {max(slots, 1)}",
        f"#define HAS_LEGAL {has_legal}",
        *tr.table_defs,
        "static int legal(const double *S, const double *A) {",
        legal,
        "}",
        "static void step(const double *S, const double *A, const double *U, const double *Z,",
        "                 double *N, double *R, double *D, double *L) {",
        "    (void)S; (void)A; (void)U; (void)Z; (void)L; *D = 0.0; *R = 0.0;",
    ]
    return "\n".join([*head, body, "}", _KERNELS, extra])


def _build(source: str) -> Path:
    cc = find_compiler()
    if cc is None:
        raise CUnavailable("no C compiler (set CC, or install cc, gcc or clang)")
    digest = hashlib.sha256((cc + "\0" + source).encode()).hexdigest()[:24]
    folder = _cache_dir()
    lib = folder / f"step-{digest}.so"
    if lib.exists():
        return lib
    src = folder / f"step-{digest}.{os.getpid()}.c"
    tmp = folder / f"step-{digest}.{os.getpid()}.so"
    src.write_text(source)
    # -O1: the step's expressions are long and flat; -O2 compiles several times
    # slower for a few percent
    cmd = [
        *cc.split(),
        "-O1",
        "-fPIC",
        "-shared",
        "-fno-math-errno",
        "-o",
        str(tmp),
        str(src),
        "-lm",
    ]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    except (OSError, subprocess.TimeoutExpired) as err:
        raise CUnavailable(f"{cc} failed: {err}") from None
    finally:
        src.unlink(missing_ok=True)
    if done.returncode != 0:
        tmp.unlink(missing_ok=True)
        raise CUnavailable(f"{cc} failed: {done.stderr.strip()[:400]}")
    os.replace(tmp, lib)  # atomic: another process may build the same
    return lib


_LOCKS: dict[str, threading.RLock] = {}
_LOCKS_GUARD = threading.Lock()


def _library_lock(path: Path) -> threading.RLock:
    """One lock per loaded library: its IDS cache and legal-action walk (and
    the tree's use of them) are the library's, shared by every `CStep` of
    that library in a process. Re-entrant: a C tree's search holds it while
    it calls back into Python, which may enumerate a state's actions."""
    with _LOCKS_GUARD:
        return _LOCKS.setdefault(str(path), threading.RLock())


_D = ctypes.POINTER(ctypes.c_double)
_I = ctypes.POINTER(ctypes.c_int)
_U64 = ctypes.POINTER(ctypes.c_uint64)


class CStep:
    """`scalar`'s step in C, with the kernels (see the module docstring).
    Raises `CUnavailable` when it cannot be built."""

    def __init__(self, scalar: ScalarStep, seed: int = 0, extra: str = ""):
        self.scalar = scalar
        self.source = c_source(scalar, extra)
        self.path = _build(self.source)
        try:
            lib = ctypes.CDLL(str(self.path))
        except OSError as err:
            raise CUnavailable(f"cannot load {self.path}: {err}") from None
        self.lib = lib
        self.lock = _library_lock(self.path)
        """Held around every call that uses the library's IDS cache (`ids_values`,
        `ids_clear`, a C tree's search): two sessions of one instance in one
        process's threads (a Dask worker's, say) take turns there instead of
        racing (ctypes lets go of the GIL during a call)."""
        sizes = (ctypes.c_int * 5)()
        lib.ippc_sizes(sizes)
        self.ns, self.na, self.nu, self.nz, self.nl = list(sizes)
        self.n_state = len(scalar.state_keys)
        self.n_action = len(scalar.action_keys)
        lib.ippc_step.argtypes = [_D, _D, _D, _D, _D, _D, _D]
        lib.ippc_sample.argtypes = [_D, _D, _U64, _D, _D]
        lib.ippc_probe.argtypes = [_D, _D, ctypes.c_int, _D, _D, _D, _D, _D, _D, _I, _I, _I, _I]
        lib.ippc_ids_values.argtypes = [
            _D,
            _D,
            ctypes.c_int,
            _D,
            ctypes.c_int,
            ctypes.c_int,
            ctypes.c_double,
            _D,
            ctypes.c_long,
        ]
        lib.ippc_ids_values.restype = ctypes.c_long
        lib.ippc_walk.argtypes = [_D, ctypes.c_int, _D, ctypes.c_int, _D, ctypes.c_double, _U64, _I]
        lib.ippc_walk.restype = ctypes.c_double
        lib.ippc_ids_clear.argtypes = []
        lib.ippc_legal.argtypes = [_D, _D]
        lib.ippc_enum_setup.argtypes = [_D, _I, _D, ctypes.c_int, ctypes.c_int, ctypes.c_int]
        lib.ippc_enum.argtypes = [_D, ctypes.c_int, _I, _D]
        lib.ippc_ids_values_enum.argtypes = [
            _D,
            _D,
            ctypes.c_int,
            ctypes.c_int,
            ctypes.c_double,
            _D,
            ctypes.c_long,
        ]
        lib.ippc_ids_values_enum.restype = ctypes.c_long
        lib.ippc_walk_enum.argtypes = [_D, ctypes.c_int, ctypes.c_double, _U64, _I]
        lib.ippc_walk_enum.restype = ctypes.c_double
        self.has_legal = bool(lib.ippc_has_legal())
        """Whether the C `legal` checks the model's constraints (False: they
        could not be translated, and it passes everything)."""
        self._enum_k = 0
        self.rng = ctypes.c_uint64(seed & (2**64 - 1))
        self._S = (ctypes.c_double * self.ns)()
        self._N = (ctypes.c_double * self.ns)()
        self._R = ctypes.c_double()
        self._taken = ctypes.c_int()
        self._acts: dict[tuple[Any, ...], Any] = {}
        self.noop = self.action(scalar.noop)
        kinds = {name: np.dtype(dt).kind for name, dt in scalar._state_dtypes.items()}
        self._casts = [
            bool if kinds[name] == "b" else int if kinds[name] in "iu" else float
            for name, _ in scalar.state_keys
        ]

    # -- conversions -----------------------------------------------------------

    def action(self, act: tuple[Any, ...]) -> Any:
        """`act` as a C array (cached)."""
        arr = self._acts.get(act)
        if arr is None:
            arr = (ctypes.c_double * self.na)(*[float(v) for v in act])
            self._acts[act] = arr
        return arr

    def block(self, acts: list[tuple[Any, ...]]) -> Any:
        """Several actions as one C array of rows (not cached)."""
        arr = (ctypes.c_double * (self.na * max(1, len(acts))))()
        na = self.na
        for i, act in enumerate(acts):
            arr[i * na : i * na + len(act)] = [float(v) for v in act]
        return arr

    def typed(self, state: StateT) -> StateT:
        """A state of the C step (doubles) with the Python step's types (the
        same dictionary key: True == 1.0 and hash(True) == hash(1.0))."""
        return tuple([f(v) for f, v in zip(self._casts, state, strict=True)])

    def _load(self, state: StateT) -> Any:
        s = self._S
        if state:
            s[: len(state)] = state
        return s

    # -- calls -----------------------------------------------------------------

    def step(
        self, state: StateT, act: tuple[Any, ...], uniforms: list[float], normals: list[float]
    ) -> tuple[StateT, float, bool, list[float]]:
        """One step with the given draws: (next, reward, done, recorded slots)."""
        u = (ctypes.c_double * self.nu)(*uniforms[: self.nu])
        z = (ctypes.c_double * self.nz)(*normals[: self.nz])
        log = (ctypes.c_double * self.nl)(*([-1.0] * self.nl))
        done = self.lib.ippc_step(
            self._load(state), self.action(act), u, z, self._N, ctypes.byref(self._R), log
        )
        return tuple(self._N[: self.n_state]), self._R.value, bool(done), list(log)

    def sample(self, state: StateT, act: tuple[Any, ...]) -> tuple[StateT, float, bool]:
        """One sampled transition (the C generator's draws)."""
        done = self.lib.ippc_sample(
            self._load(state),
            self.action(act),
            ctypes.byref(self.rng),
            self._N,
            ctypes.byref(self._R),
        )
        return tuple(self._N[: self.n_state]), self._R.value, bool(done)

    def probe(
        self, state: StateT, block: Any, n: int, draws: tuple[Any, Any, Any, Any]
    ) -> list[tuple[int, bool, StateT, float, bool, bool]]:
        """The kept actions of the `n` rows of `block` (see `ippc_probe`): per
        kept action its row, whether it is deterministic, the first probe's
        successor, reward and done, and whether both probes' rewards agree."""
        if n == 0:
            return []
        ns = self.ns
        n1 = (ctypes.c_double * (ns * n))()
        r1 = (ctypes.c_double * n)()
        d1 = (ctypes.c_int * n)()
        det = (ctypes.c_int * n)()
        same_r = (ctypes.c_int * n)()
        keep = (ctypes.c_int * n)()
        if (
            self.lib.ippc_probe(self._load(state), block, n, *draws, n1, r1, d1, det, same_r, keep)
            < 0
        ):
            raise MemoryError("ippc_probe")
        k = self.n_state
        return [
            (a, bool(det[a]), tuple(n1[a * ns : a * ns + k]), r1[a], bool(d1[a]), bool(same_r[a]))
            for a in range(n)
            if keep[a]
        ]

    def draw_block(self, uniforms: list[float], normals: list[float]) -> tuple[Any, Any]:
        """Fixed draws as C arrays (for `probe`)."""
        u = (ctypes.c_double * self.nu)(*(list(uniforms) + [0.5] * self.nu)[: self.nu])
        z = (ctypes.c_double * self.nz)(*(list(normals) + [0.0] * self.nz)[: self.nz])
        return u, z

    def ids_values(
        self,
        state: StateT,
        kept: Any,
        n_kept: int,
        cands: Any,
        n_cands: int,
        depth: int,
        gamma: float,
        token: int,
    ) -> tuple[list[float], int]:
        """IDS values of the `n_kept` actions of block `kept` (see
        `ippc_ids_values`), and the steps made. `token` (an int) names the
        candidates and gamma: a call with another token clears the cache."""
        out = (ctypes.c_double * max(1, n_kept))()
        with self.lock:
            steps = self.lib.ippc_ids_values(
                self._load(state), kept, n_kept, cands, n_cands, depth, gamma, out, token
            )
        return list(out[:n_kept]), int(steps)

    def legal(self, state: StateT, act: tuple[Any, ...]) -> bool:
        """The C `legal` (see `ScalarStep.legal`; True where there is none)."""
        return bool(self.lib.ippc_legal(self._load(state), self.action(act)))

    def enum_setup(self, grounds: list[tuple[int, float]], k: int, limit: int) -> None:
        """What `enumerate` may set: (action slot, value) pairs, at most `k` at
        once, counting up to `limit` joint actions."""
        n = len(grounds)
        pos = (ctypes.c_int * max(1, n))(*[g for g, _ in grounds])
        val = (ctypes.c_double * max(1, n))(*[float(v) for _, v in grounds])
        with self.lock:
            if self.lib.ippc_enum_setup(self.noop, pos, val, n, k, limit) < 0:
                raise MemoryError("ippc_enum_setup")
        self._enum_k = k

    def enumerate(self, state: StateT, cap: int) -> tuple[int, list[tuple[int, ...]]]:
        """The legal joint actions of `state` built by C (see `ippc_enum`):
        how many there are (-1: noop illegal, or more than the limit: the
        limit plus one), and the first `cap`, each as the indices (into
        `enum_setup`'s list) of the groundings it sets."""
        k = max(1, self._enum_k)
        g = (ctypes.c_int * (k * max(1, cap)))()
        with self.lock:
            n = int(self.lib.ippc_enum(self._load(state), cap, g, None))
        rows = []
        for i in range(min(max(n, 0), cap)):
            row = g[i * k : (i + 1) * k]
            rows.append(tuple(x for x in row if x >= 0) if self._enum_k else ())
        return n, rows

    def ids_values_enum(
        self, state: StateT, kept: Any, n_kept: int, depth: int, gamma: float, token: int
    ) -> tuple[list[float], int]:
        """`ids_values` with every state's candidates from `enumerate`."""
        out = (ctypes.c_double * max(1, n_kept))()
        with self.lock:
            steps = self.lib.ippc_ids_values_enum(
                self._load(state), kept, n_kept, depth, gamma, out, token
            )
        return list(out[:n_kept]), int(steps)

    def ids_clear(self) -> None:
        with self.lock:
            self.lib.ippc_ids_clear()

    def walk(
        self, state: StateT, n: int, pool: Any, n_pool: int, gamma: float
    ) -> tuple[float, int, bool]:
        """A roll-out of up to `n` steps (noop when `n_pool` is 0): (its
        discounted return, the steps taken, whether the run ended)."""
        total = self.lib.ippc_walk(
            self._load(state),
            n,
            pool,
            n_pool,
            self.noop,
            gamma,
            ctypes.byref(self.rng),
            ctypes.byref(self._taken),
        )
        taken = int(self._taken.value)
        return float(total), abs(taken), taken < 0

    def walk_enum(self, state: StateT, n: int, gamma: float) -> tuple[float, int, bool]:
        """A roll-out of up to `n` steps whose actions are noop or one grounding
        of `enum_setup`'s legal in the state (see `ippc_walk_enum`), as `walk`."""
        with self.lock:
            total = self.lib.ippc_walk_enum(
                self._load(state), n, gamma, ctypes.byref(self.rng), ctypes.byref(self._taken)
            )
        taken = int(self._taken.value)
        return float(total), abs(taken), taken < 0
