"""The parser: every construct, precedence, positions, and the shared files."""

from __future__ import annotations

from pathlib import Path

import pytest
from ippc.rddl import RDDLSyntaxError, parse, parse_expr, parse_file
from ippc.rddl import ast as A


def pv(name: str, *args: A.Expr) -> A.PVar:
    return A.PVar(name, tuple(args))


def b(op: str, left: A.Expr, right: A.Expr) -> A.Binary:
    return A.Binary(op, left, right)


a, bb, c, d = pv("a"), pv("b"), pv("c"), pv("d")


@pytest.mark.parametrize(
    "text, tree",
    [
        ("a + b * c", b("+", a, b("*", bb, c))),
        ("a - b - c", b("-", b("-", a, bb), c)),
        ("a / b * c", b("*", b("/", a, bb), c)),
        ("-a * b", b("*", A.Unary("-", a), bb)),
        # rddlsim gives ~ the precedence of unary minus: (~a) == b
        ("~a == b", b("==", A.Unary("~", a), bb)),
        ("~(a == b)", A.Unary("~", b("==", a, bb))),
        ("a ^ b | c", b("|", b("^", a, bb), c)),
        ("a & b", b("^", a, bb)),
        ("a | b => c", b("=>", b("|", a, bb), c)),
        ("a => b <=> c", b("<=>", b("=>", a, bb), c)),
        ("a < b + 1", b("<", a, b("+", bb, A.Const(1)))),
        ("a == b ^ c", b("^", b("==", a, bb), c)),
        # prefix forms extend as far right as they can
        ("if (a) then 1 else 2 + 3", A.If(a, A.Const(1), b("+", A.Const(2), A.Const(3)))),
        (
            "sum_{?x : t} f(?x) + 1",
            A.Aggregation(
                "sum", (A.TypedVar("?x", "t"),), b("+", pv("f", A.Var("?x")), A.Const(1))
            ),
        ),
        (
            "a + exists_{?x : t} f(?x) ^ g",
            b(
                "+",
                a,
                A.Aggregation(
                    "exists", (A.TypedVar("?x", "t"),), b("^", pv("f", A.Var("?x")), pv("g"))
                ),
            ),
        ),
        ("[a + b] * c", b("*", b("+", a, bb), c)),
    ],
)
def test_precedence(text: str, tree: A.Expr) -> None:
    assert parse_expr(text) == tree


def test_literals_keep_their_kind() -> None:
    assert parse_expr("1") == A.Const(1)
    assert parse_expr("1.0") == A.Const(1.0)
    assert parse_expr("1") != A.Const(1.0)
    assert parse_expr("true") == A.Const(True)
    assert parse_expr("true") != A.Const(1)
    assert parse_expr(".25") == A.Const(0.25)
    assert parse_expr("1e-3") == A.Const(0.001)
    assert parse_expr("pos-inf") == A.Const(float("inf"))
    assert parse_expr("@low") == A.EnumLit("@low")
    assert parse_expr("$c1") == A.ObjectLit("c1")


@pytest.mark.parametrize(
    "text, tree",
    [
        ("running'(?x)", A.PVar("running", (A.Var("?x"),), primed=True)),
        ("f(g(?x), @a, $o)", pv("f", pv("g", A.Var("?x")), A.EnumLit("@a"), A.ObjectLit("o"))),
        ("x.default", A.PVar("x", default=True)),
        ("exp[x]", A.Function("exp", (pv("x"),))),
        ("max[a, b]", A.Function("max", (a, bb))),
        ("Normal(0.0, v)", A.Distribution("Normal", (A.Const(0.0), pv("v")))),
        ("Bernoulli(p)", A.Distribution("Bernoulli", (pv("p"),))),
        (
            "Discrete(t, @a : 0.3, @b : otherwise)",
            A.Discrete(
                "Discrete",
                "t",
                (
                    A.DiscreteCase(A.EnumLit("@a"), A.Const(0.3)),
                    A.DiscreteCase(A.EnumLit("@b"), None),
                ),
            ),
        ),
        (
            "Discrete_{?i : item}[w(?i)]",
            A.DiscreteOver("Discrete", (A.TypedVar("?i", "item"),), pv("w", A.Var("?i"))),
        ),
        (
            "switch (x) { case @a : 1, default : 2 }",
            A.Switch(pv("x"), (A.Case(A.EnumLit("@a"), A.Const(1)), A.Case(None, A.Const(2)))),
        ),
        (
            "cholesky[row=?a, col=?b][cov(?a, ?b)]",
            A.MatrixOp("cholesky", "?a", "?b", pv("cov", A.Var("?a"), A.Var("?b"))),
        ),
        (
            "MultivariateNormal[?x](m(?x), s(?x, ?y))",
            A.VectorDistribution(
                "MultivariateNormal",
                ("?x",),
                (pv("m", A.Var("?x")), pv("s", A.Var("?x"), A.Var("?y"))),
            ),
        ),
        (
            "argmax_{?s : shape} r(?s)",
            A.Aggregation("argmax", (A.TypedVar("?s", "shape"),), pv("r", A.Var("?s"))),
        ),
    ],
)
def test_expression_forms(text: str, tree: A.Expr) -> None:
    assert parse_expr(text) == tree


DOMAIN = """\
domain toy {
    requirements = { reward-deterministic, concurrent };
    types {
        thing : object;
        widget : thing;
        level : {@low, @high};
    };
    pvariables {
        W : { non-fluent, real, default = -0.5 };
        on(thing) : { state-fluent, bool, default = false };
        lvl : { state-fluent, level, default = @low };
        n(thing) : { interm-fluent, int, level = 1 };
        o(thing) : { observ-fluent, bool };
        go(thing) : { action-fluent, bool, default = false };
    };
    cpfs {
        n(?t) = on(?t) + 1;
        on'(?t) = go(?t) | on(?t);
        lvl' = if (exists_{?t : thing} on(?t)) then @high else @low;
        o(?t) = on'(?t);
    };
    reward = sum_{?t : thing} [on(?t) * W];
    action-preconditions { forall_{?t : thing} [go(?t) => ~on(?t)]; };
    state-invariants { lvl == @low | lvl == @high; };
    termination { forall_{?t : thing} on(?t); };
}
"""

INSTANCE_2018 = """\
instance toy_1 {
    domain = toy;
    objects { thing : {t1, t2}; widget : {w1}; };
    non-fluents { W = 2.5; };
    init-state { on(t1); ~on(t2); };
    horizon = pos-inf;
    discount = 0.9;
}
"""


def test_blocks_and_positions() -> None:
    f = parse(DOMAIN + INSTANCE_2018, "toy.rddl")
    (dom,) = f.domains
    assert dom.name == "toy"
    assert dom.requirements == ("reward-deterministic", "concurrent")
    assert [t.kind for t in dom.types] == ["object", "sub", "enum"]
    assert dom.types[1].parent == "thing"
    assert dom.types[2].values == ("@low", "@high")
    w = dom.pvariables[0]
    assert (w.name, w.kind, w.range, w.default) == ("W", "non-fluent", "real", A.Const(-0.5))
    assert dom.pvariables[3].level == A.Const(1)
    assert dom.pvariables[4].default is None
    assert [(c.name, c.primed, c.params) for c in dom.cpfs] == [
        ("n", False, ("?t",)),
        ("on", True, ("?t",)),
        ("lvl", True, ()),
        ("o", False, ("?t",)),
    ]
    assert len(dom.action_preconditions) == 1 and len(dom.termination) == 1
    # positions are 1-based and point at the construct
    assert dom.pvariables[1].loc == A.Loc("toy.rddl", 10, 9)
    assert dom.cpfs[1].loc == A.Loc("toy.rddl", 18, 9)
    (inst,) = f.instances
    assert inst.horizon == A.POS_INF and inst.discount == 0.9
    assert inst.max_nondef_actions is None and inst.non_fluents is None
    assert [o.names for o in inst.objects] == [("t1", "t2"), ("w1",)]
    assert inst.init_state is not None
    assert [(s.name, s.args, s.negated) for s in inst.init_state] == [
        ("on", ("t1",), False),
        ("on", ("t2",), True),
    ]
    assert inst.init_state[1].resolved_value() == A.Const(False)


def test_ippc2011_layout_and_terminate_when() -> None:
    text = """
    non-fluents nf1 { domain = toy; objects { thing : {a}; }; non-fluents { W = 1; }; }
    instance i1 { domain = toy; non-fluents = nf1; init-state { on(a) = true; };
                  max-nondef-actions = pos-inf; horizon = terminate-when (exists_{?t : thing} on(?t)); discount = 1.0; }
    """
    f = parse(text)
    assert f.non_fluents[0].values[0].value == A.Const(1)
    inst = f.instances[0]
    assert inst.non_fluents == "nf1" and inst.max_nondef_actions == A.POS_INF
    assert isinstance(inst.horizon, A.Aggregation)


def test_syntax_errors_in_two_blocks_are_both_reported() -> None:
    text = (
        "domain d {\n  pvariables { x : { state-fluent, bool, default = false } };\n}\n"
        "instance i {\n  domain = d;\n  horizon = ;\n}\n"
    )
    with pytest.raises(RDDLSyntaxError) as info:
        parse(text, "two.rddl")
    lines = [(d.line, d.column) for d in info.value.diagnostics]
    assert lines == [(2, 60), (6, 13)]
    assert "expected ';'" in info.value.diagnostics[0].message


def test_shared_rddl_files_parse(rddlsim_rddl: Path) -> None:
    files = sorted(rddlsim_rddl.glob("*.rddl"))
    assert len(files) >= 10
    for f in files:
        parsed = parse_file(f)
        assert parsed.domains or parsed.instances or parsed.non_fluents, f
