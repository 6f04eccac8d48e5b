"""The one-state step compiled to C.

`ScalarStep` writes an instance's transition as one Python function over
scalars; a step costs some microseconds of interpreted Python, and a tree
search makes tens of them for each node it expands. `CStep` translates that
function, node by node of its Python syntax tree, into C over doubles,
compiles it (`cbuild`: the system's C compiler, a private cache) into a
shared library, and loads it with ctypes: `step` (given draws, recording
the probability at every Bernoulli and Discrete site and the standard
deviation at every Normal site), `sample` (one sampled transition) and
`legal` (the action preconditions and state-action constraints).

The unit compiled is one C text (`c_source`): csrc/prelude.h (Python's
arithmetic helpers in C), the instance's sizes, tables, `legal` and `step`
as translated, csrc/step_api.c (the entry points and the generator), then
any C text of the caller that calls them (mcts's search kernels, in
planners/mcts/csrc/). csrc/step.h describes that interface and stands in
for the generated part when a file of csrc/ is read alone.

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

Imports `scalar` (whose source and tables it translates) and `cbuild`.
"""

from __future__ import annotations

import ast
import ctypes
from pathlib import Path
from typing import Any

import numpy as np

from .cbuild import CUnavailable, build, find_compiler
from .scalar import ScalarStep

__all__ = ["CStep", "CUnavailable", "c_source", "find_compiler"]

StateT = tuple[Any, ...]


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

_CSRC = Path(__file__).with_name("csrc")


def _csrc(name: str) -> str:
    """The text of a file of csrc/ (package data)."""
    return (_CSRC / name).read_text(encoding="utf-8")


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


def c_source(scalar: ScalarStep, extra: str = "") -> str:
    """The C unit of `scalar`'s step (see the module docstring), then
    `extra` (C text that may call it; raises `CUnavailable`)."""
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
        _csrc("prelude.h"),
        "#define IPPC_STEP_UNIT 1",
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
    return "\n".join([*head, body, "}", _csrc("step_api.c"), extra])


_D = ctypes.POINTER(ctypes.c_double)
_U64 = ctypes.POINTER(ctypes.c_uint64)


class CStep:
    """`scalar`'s step in C (see the module docstring), with `extra` C text
    compiled after it. Raises `CUnavailable` when it cannot be built."""

    def __init__(self, scalar: ScalarStep, seed: int = 0, extra: str = ""):
        self.scalar = scalar
        self.source = c_source(scalar, extra)
        self.path = build(self.source)
        try:
            lib = ctypes.CDLL(str(self.path))
        except OSError as err:
            raise CUnavailable(f"cannot load {self.path}: {err}") from None
        self.lib = lib
        sizes = (ctypes.c_int * 5)()
        lib.ippc_sizes(sizes)
        self.ns, self.na, self.nu, self.nz, self.nl = list(sizes)
        self.n_state = len(scalar.state_keys)
        self.n_action = len(scalar.action_keys)
        lib.ippc_step.argtypes = [_D, _D, _D, _D, _D, _D, _D]
        lib.ippc_sample.argtypes = [_D, _D, _U64, _D, _D]
        lib.ippc_legal.argtypes = [_D, _D]
        self.has_legal = bool(lib.ippc_has_legal())
        """Whether the C `legal` checks the model's constraints (False: they
        could not be translated, and it passes everything)."""
        self.rng = ctypes.c_uint64(seed & (2**64 - 1))
        self._S = (ctypes.c_double * self.ns)()
        self._N = (ctypes.c_double * self.ns)()
        self._R = ctypes.c_double()
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

    def legal(self, state: StateT, act: tuple[Any, ...]) -> bool:
        """The C `legal` (see `ScalarStep.legal`; True where there is none)."""
        return bool(self.lib.ippc_legal(self._load(state), self.action(act)))
