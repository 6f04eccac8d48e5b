"""Bad RDDL inputs and the diagnostics they give.

Every case is the small valid `lights` model below (`BASE`, one file with a
domain, a non-fluents block and an instance) changed by one small edit. Each
case states, literally, the file, line and column (1-based) and the kind of
the FIRST diagnostic, and substrings its message should contain. As a check
on the table itself (not on the front end), each case also states the text
that stands at that line and column of the edited input.

Where a diagnostic points: a syntax error at the token (or character) that
cannot stand there, or at the end of the file when the file ends too soon; a
semantic error at the start of the offending construct: for a binary
operator the operator itself, for a pvariable reference its name, for a
declaration its name, for an assignment in init-state or non-fluents its name
(a value of the wrong type there: the value), for a problem of the instance as
a whole the instance's name.

Cases the front end gets wrong today are marked xfail(strict=True) with the
reason; the expectation is not weakened to match.
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from pathlib import Path

import pytest
from ippc.rddl import (
    RDDLError,
    RDDLSemanticError,
    RDDLSyntaxError,
    load,
    parse,
)

BASE = """\
domain lights {
    types {
        room : object;
        house : object;
        bright : {@dim, @full};
        speed : {@slow, @fast};
    };
    pvariables {
        WATTS(room) : { non-fluent, real, default = 1.0 };
        IN(room, house) : { non-fluent, bool, default = false };
        on(room) : { state-fluent, bool, default = false };
        mode : { state-fluent, bright, default = @dim };
        clicks : { state-fluent, int, default = 0 };
        flip(room) : { action-fluent, bool, default = false };
        lit : { interm-fluent, int };
    };
    cpfs {
        lit = sum_{?r : room} [on(?r)];
        on'(?r) = if (flip(?r)) then ~on(?r) else on(?r);
        mode' = if (lit > 1) then @full else @dim;
        clicks' = clicks + sum_{?r : room} [flip(?r)];
    };
    reward = sum_{?r : room} [WATTS(?r) * on(?r)] - lit;
}

non-fluents lights_nf {
    domain = lights;
    objects {
        room : {r1, r2};
        house : {h1};
    };
    non-fluents {
        WATTS(r1) = 2.0;
        IN(r1, h1);
    };
}

instance lights_inst {
    domain = lights;
    non-fluents = lights_nf;
    init-state {
        on(r1) = true;
    };
    max-nondef-actions = 1;
    horizon = 10;
    discount = 1.0;
}
"""
# Line numbers of BASE, for reading the table:
#  11 on(room) decl       18 lit cpf      19 on' cpf      20 mode' cpf
#  23 reward              26 non-fluents lights_nf        29 room objects
#  30 house objects       33-34 non-fluent values         38 instance lights_inst
#  42 on(r1) = true       45 horizon      46 discount

ONE = "lights.rddl"  # the whole model in one file
DOM = "lights_domain.rddl"  # split: the domain (BASE lines 1-25) ...
INST = "lights_inst.rddl"  # ... and the rest (BASE line L is line L-25 here)


@dataclass(frozen=True)
class Case:
    edits: tuple[tuple[str, str], ...]  # (old, new): old occurs exactly once
    line: int
    column: int
    kind: str
    message: tuple[str, ...]  # substrings of the first diagnostic's message
    at: str  # the text at (line, column) of the edited file; "" = end of line
    file: str = ONE
    split: bool = False


def edit(text: str, edits: tuple[tuple[str, str], ...]) -> str:
    for old, new in edits:
        assert text.count(old) == 1, f"edit target not unique: {old!r}"
        text = text.replace(old, new, 1)
    return text


def files_of(case: Case) -> dict[str, str]:
    text = edit(BASE, case.edits)
    if not case.split:
        return {ONE: text}
    cut = text.index("non-fluents lights_nf {")
    return {DOM: text[:cut], INST: text[cut:]}


def write(tmp_path: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        (tmp_path / name).write_text(text, encoding="utf-8")


def case(
    id: str,
    edits: list[tuple[str, str]] | tuple[str, str],
    line: int,
    column: int,
    kind: str,
    message: str | tuple[str, ...],
    at: str,
    *,
    file: str | None = None,
    split: bool = False,
    xfail: str | None = None,
) -> object:
    if isinstance(edits, tuple):
        edits = [edits]
    c = Case(
        tuple(edits),
        line,
        column,
        kind,
        (message,) if isinstance(message, str) else message,
        at,
        file or (INST if split else ONE),
        split,
    )
    if xfail:
        FIRST_DIAGNOSTIC_XFAIL[id] = xfail
    return pytest.param(c, id=id)


# Cases whose first diagnostic is wrong today (reason by case id); set by case().
FIRST_DIAGNOSTIC_XFAIL: dict[str, str] = {}


def _with_xfail(p: object, reasons: dict[str, str]) -> object:
    reason = reasons.get(p.id)  # type: ignore[attr-defined]
    marks = [pytest.mark.xfail(strict=True, reason=reason)] if reason else []
    return pytest.param(*p.values, id=p.id, marks=marks)  # type: ignore[attr-defined]


# ------------------------------------------------------------ syntax

SYNTAX = [
    case(
        "missing-brace-at-end",
        ("    discount = 1.0;\n}\n", "    discount = 1.0;\n"),
        46,
        20,
        "syntax",
        ("end of file", "'}'"),
        "",
    ),
    case(
        "missing-brace-of-domain",
        ("- lit;\n}\n", "- lit;\n\n"),
        26,
        1,
        "syntax",
        ("unexpected 'non-fluents'", "'}'"),
        "non-fluents",
    ),
    case("extra-brace", ("- lit;\n}\n", "- lit;\n}}\n"), 24, 2, "syntax", "unexpected '}'", "}"),
    case(
        "missing-semicolon-after-cpf",
        ("[on(?r)];", "[on(?r)]"),
        19,
        9,
        "syntax",
        ("on'", "expected", "';'"),
        "on'",
    ),
    case(
        "misspelt-pvariables",
        ("    pvariables {", "    pvariable {"),
        8,
        5,
        "syntax",
        ("'pvariable'", "expected", "did you mean 'pvariables'"),
        "pvariable",
    ),
    case(
        "misspelt-state-fluent",
        ("on(room) : { state-fluent,", "on(room) : { state-fluents,"),
        11,
        22,
        "syntax",
        ("'state-fluents'", "expected", "did you mean 'state-fluent'"),
        "state-fluents",
    ),
    case(
        "misspelt-cpfs",
        ("    cpfs {", "    cpf {"),
        17,
        5,
        "syntax",
        ("'cpf'", "expected", "did you mean 'cpfs'"),
        "cpf",
    ),
    case(
        "misspelt-instance",
        ("instance lights_inst {", "instanse lights_inst {"),
        38,
        1,
        "syntax",
        ("'instanse'", "expected", "did you mean 'instance'"),
        "instanse",
    ),
    case(
        "illegal-character",
        ("if (lit > 1)", "if (lit # 1)"),
        20,
        25,
        "syntax",
        "unexpected character '#'",
        "#",
    ),
    case(
        "unterminated-expression",
        ("- lit;\n}", "- lit + ;\n}"),
        23,
        59,
        "syntax",
        ("unexpected ';'", "expected an expression"),
        ";",
    ),
    case(
        "split-illegal-character-in-domain-file",
        ("if (lit > 1)", "if (lit # 1)"),
        20,
        25,
        "syntax",
        "unexpected character '#'",
        "#",
        split=True,
        file=DOM,
    ),
    case(
        "split-misspelt-instance-in-instance-file",
        ("instance lights_inst {", "instanse lights_inst {"),
        13,
        1,
        "syntax",
        "did you mean 'instance'",
        "instanse",
        split=True,
    ),
]

# ----------------------------------------------------------- semantic

SEMANTIC = [
    # names
    case(
        "undefined-fluent-in-cpf",
        ("then ~on(?r)", "then ~onn(?r)"),
        19,
        39,
        "unknown-name",
        "'onn'",
        "onn(",
    ),
    case(
        "undefined-fluent-in-reward",
        ("[WATTS(?r) * on(?r)] - lit", "[WATS(?r) * on(?r)] - lit"),
        23,
        31,
        "unknown-name",
        "'WATS'",
        "WATS(",
    ),
    case(
        "undefined-bare-name-in-reward",
        ("- lit;\n}", "- lite;\n}"),
        23,
        53,
        "unknown-name",
        "'lite'",
        "lite;",
    ),
    case(
        "unbound-variable",
        ("else on(?r);", "else on(?y);"),
        19,
        54,
        "unknown-variable",
        "'?y'",
        "?y",
    ),
    case(
        "unknown-type-in-parameter-list",
        ("on(room) : {", "on(rom) : {"),
        11,
        9,
        "unknown-type",
        "'rom'",
        "on(rom)",
    ),
    case(
        "unknown-range-type",
        ("lit : { interm-fluent, int };", "lit : { interm-fluent, integer };"),
        15,
        9,
        "unknown-type",
        "'integer'",
        "lit :",
    ),
    case(
        "unknown-type-in-quantifier",
        ("lit = sum_{?r : room}", "lit = sum_{?r : rooms}"),
        18,
        20,
        "unknown-type",
        "'rooms'",
        "?r : rooms",
    ),
    case(
        "unknown-function", ("- lit;\n}", "- foo[lit];\n}"), 23, 53, "unknown-name", "'foo", "foo["
    ),
    case(
        "unknown-aggregation",
        ("lit = sum_{", "lit = sumx_{"),
        18,
        15,
        "unknown-name",
        "'sumx",
        "sumx_{",
    ),
    case(
        "unknown-enum-value",
        ("else @dim;", "else @dark;"),
        20,
        46,
        "unknown-name",
        "'@dark'",
        "@dark",
    ),
    case(
        "cpf-for-undeclared-pvariable",
        ("    cpfs {\n", "    cpfs {\n        dark' = false;\n"),
        18,
        9,
        "unknown-name",
        "'dark",
        "dark'",
    ),
    case(
        "split-undefined-fluent-in-domain-file",
        ("then ~on(?r)", "then ~onn(?r)"),
        19,
        39,
        "unknown-name",
        "'onn'",
        "onn(",
        split=True,
        file=DOM,
    ),
    # arity
    case(
        "arity-of-pvariable-in-expression",
        ("if (flip(?r))", "if (flip(?r, ?r))"),
        19,
        23,
        "arity",
        "'flip'",
        "flip(?r, ?r)",
    ),
    case(
        "arity-in-init-state",
        ("on(r1) = true;", "on(r1, r2) = true;"),
        42,
        9,
        "arity",
        "'on'",
        "on(r1, r2)",
    ),
    case(
        "cpf-parameter-count", ("on'(?r) =", "on'(?r, ?s) ="), 19, 9, "arity", "'on'", "on'(?r, ?s)"
    ),
    case(
        "normal-with-one-argument",
        ("- lit;\n}", "- Normal(lit);\n}"),
        23,
        53,
        "arity",
        "Normal",
        "Normal(",
    ),
    # types
    case(
        "enum-value-where-object-expected",
        ("if (flip(?r))", "if (flip(@dim))"),
        19,
        28,
        "type",
        ("'flip'", "@dim"),
        "@dim",
    ),
    case(
        "object-of-wrong-type",
        ("else on(?r);", "else on($h1);"),
        19,
        54,
        "type",
        ("'h1'", "'house'", "'room'"),
        "$h1",
    ),
    case(
        "bool-compared-with-real",
        ("[on(?r)];", "[on(?r) == WATTS(?r)];"),
        18,
        39,
        "type",
        ("bool", "real"),
        "==",
    ),
    case(
        "enum-compared-with-number",
        ("if (lit > 1)", "if (mode == 1)"),
        20,
        26,
        "type",
        ("'=='", "'bright'"),
        "==",
    ),
    case(
        "enum-compared-with-other-enum",
        ("if (lit > 1)", "if (mode == @slow)"),
        20,
        26,
        "type",
        ("'bright'", "'speed'"),
        "==",
    ),
    case(
        "arithmetic-on-enum",
        ("if (lit > 1)", "if (mode + 1 > 1)"),
        # the enum operand is the culprit, so it is what the error points at
        20,
        21,
        "type",
        ("'+'", "'bright'"),
        "mode",
    ),
    case(
        "if-branches-enum-and-number",
        ("then @full else @dim;", "then @full else 0;"),
        20,
        17,
        "type",
        ("'bright'", "int"),
        "if (",
    ),
    case(
        "cpf-gives-number-for-enum-fluent",
        ("mode' = if (lit > 1) then @full else @dim;", "mode' = lit;"),
        20,
        17,
        "type",
        ("'mode'", "'bright'"),
        "lit;",
    ),
    case(
        "default-of-wrong-type",
        ("state-fluent, bool, default = false", "state-fluent, bool, default = 1.5"),
        11,
        52,
        "type",
        "1.5",
        "1.5",
    ),
    # cpfs
    case(
        "missing-cpf-for-state-fluent",
        ("        mode' = if (lit > 1) then @full else @dim;\n", "        // mode is left out\n"),
        12,
        9,
        "missing-cpf",
        "'mode'",
        "mode :",
    ),
    case(
        "missing-cpf-for-interm-fluent",
        ("        lit = sum_{?r : room} [on(?r)];\n", "        // lit is left out\n"),
        15,
        9,
        "missing-cpf",
        "'lit'",
        "lit :",
    ),
    case(
        "cpf-for-non-fluent",
        ("    cpfs {\n", "    cpfs {\n        WATTS(?r) = 1.0;\n"),
        18,
        9,
        "bad-cpf",
        ("'WATTS'", "non-fluent"),
        "WATTS(?r)",
    ),
    case(
        "cpf-for-action-fluent",
        ("    cpfs {\n", "    cpfs {\n        flip(?r) = false;\n"),
        18,
        9,
        "bad-cpf",
        ("'flip'", "action-fluent"),
        "flip(?r)",
    ),
    case(
        "unprimed-cpf-for-state-fluent",
        ("on'(?r) =", "on(?r) ="),
        19,
        9,
        "bad-cpf",
        "on'",
        "on(?r) =",
    ),
    case(
        "primed-cpf-for-interm-fluent",
        ("lit = sum_{?r : room} [on(?r)];", "lit' = sum_{?r : room} [on(?r)];"),
        18,
        9,
        "bad-cpf",
        ("'lit'", "interm-fluent"),
        "lit'",
    ),
    # duplicates
    case(
        "duplicate-pvariable",
        (
            "        lit : { interm-fluent, int };\n",
            "        lit : { interm-fluent, int };\n        lit : { interm-fluent, real };\n",
        ),
        16,
        9,
        "duplicate-definition",
        "'lit'",
        "lit : { interm-fluent, real }",
    ),
    case(
        "duplicate-type",
        ("        house : object;\n", "        house : object;\n        room : object;\n"),
        5,
        9,
        "duplicate-definition",
        "'room'",
        "room : object",
    ),
    case(
        "duplicate-object",
        ("room : {r1, r2};", "room : {r1, r2, r1};"),
        29,
        25,
        "duplicate-definition",
        "'r1'",
        "r1}",
    ),
    case(
        "duplicate-cpf",
        ("        mode' = if", "        on'(?r) = on(?r);\n        mode' = if"),
        20,
        9,
        "duplicate-definition",
        "on'",
        "on'(?r) = on(?r)",
    ),
    # init-state and non-fluents values
    case(
        "init-state-for-unknown-fluent",
        ("on(r1) = true;", "off(r1) = true;"),
        42,
        9,
        "unknown-name",
        "'off'",
        "off(r1)",
    ),
    case(
        "init-state-for-non-fluent",
        ("on(r1) = true;", "WATTS(r1) = 3.0;"),
        42,
        9,
        "bad-assignment",
        ("'WATTS'", "non-fluent"),
        "WATTS(r1)",
    ),
    case(
        "non-fluents-block-sets-state-fluent",
        ("        IN(r1, h1);\n", "        IN(r1, h1);\n        on(r2) = true;\n"),
        35,
        9,
        "bad-assignment",
        ("'on'", "state-fluent"),
        "on(r2)",
    ),
    case(
        "init-state-unknown-object",
        ("on(r1) = true;", "on(r9) = true;"),
        42,
        9,
        "unknown-object",
        "'r9'",
        "on(r9)",
    ),
    case(
        "split-init-state-unknown-object",
        ("on(r1) = true;", "on(r9) = true;"),
        17,
        9,
        "unknown-object",
        "'r9'",
        "on(r9)",
        split=True,
    ),
    case(
        "non-fluent-argument-of-wrong-type",
        ("IN(r1, h1);", "IN(h1, h1);"),
        34,
        9,
        "type",
        ("'h1'", "'room'"),
        "IN(h1, h1)",
    ),
    case(
        "conflicting-init-state-values",
        ("        on(r1) = true;\n", "        on(r1) = true;\n        on(r1) = false;\n"),
        43,
        9,
        "duplicate-definition",
        "on(r1)",
        "on(r1) = false",
    ),
    case(
        "init-state-real-for-bool",
        ("on(r1) = true;", "on(r1) = 0.5;"),
        42,
        18,
        "type",
        "0.5",
        "0.5;",
    ),
    case(
        "init-state-real-for-int",
        ("        on(r1) = true;\n", "        on(r1) = true;\n        clicks = 1.5;\n"),
        43,
        18,
        "type",
        "1.5",
        "1.5;",
    ),
    case(
        "init-state-value-not-in-enum",
        ("        on(r1) = true;\n", "        on(r1) = true;\n        mode = @slow;\n"),
        43,
        16,
        "type",
        ("'@slow'", "'bright'"),
        "@slow",
    ),
    case(
        "objects-for-unknown-type",
        ("house : {h1};", "home : {h1};"),
        30,
        9,
        "unknown-type",
        "'home'",
        "home :",
    ),
    # the instance as a whole
    case(
        "instance-names-missing-domain",
        (
            "    domain = lights;\n    non-fluents = lights_nf;",
            "    domain = light;\n    non-fluents = lights_nf;",
        ),
        38,
        10,
        "unknown-domain",
        "'light'",
        "lights_inst {",
    ),
    case(
        "split-instance-names-missing-domain",
        (
            "    domain = lights;\n    non-fluents = lights_nf;",
            "    domain = light;\n    non-fluents = lights_nf;",
        ),
        13,
        10,
        "unknown-domain",
        "'light'",
        "lights_inst {",
        split=True,
    ),
    case(
        "instance-names-missing-non-fluents",
        ("non-fluents = lights_nf;", "non-fluents = lights_nff;"),
        38,
        10,
        "unknown-non-fluents",
        "'lights_nff'",
        "lights_inst {",
    ),
    case(
        "non-fluents-block-names-missing-domain",
        (
            "non-fluents lights_nf {\n    domain = lights;",
            "non-fluents lights_nf {\n    domain = light;",
        ),
        26,
        13,
        "unknown-domain",
        "'light'",
        "lights_nf {",
    ),
    case(
        "missing-horizon",
        ("    horizon = 10;\n", "    // no horizon\n"),
        38,
        10,
        "missing-horizon",
        "horizon",
        "lights_inst {",
    ),
]

CASES = SYNTAX + SEMANTIC


def _text_at(text: str, line: int, column: int) -> str:
    lines = text.splitlines()
    assert 1 <= line <= len(lines), (line, len(lines))
    src = lines[line - 1]
    assert 1 <= column <= len(src) + 1, (column, src)
    return src[column - 1 :]


# ------------------------------------------------------------- tests


def test_base_loads(tmp_path: Path) -> None:
    write(tmp_path, {ONE: BASE})
    models = load(tmp_path)
    assert list(models) == ["lights_inst"]
    m = models["lights_inst"]
    assert m.horizon == 10
    assert set(m.pvariables) == {"WATTS", "IN", "on", "mode", "clicks", "flip", "lit"}


def test_split_base_loads(tmp_path: Path) -> None:
    c = Case((), 1, 1, "", (), "", split=True)
    write(tmp_path, files_of(c))
    assert list(load(tmp_path)) == ["lights_inst"]


@pytest.mark.parametrize("c", CASES)
def test_table_is_consistent(c: Case) -> None:
    """The stated line and column are where the stated text is (checks the
    table, not the front end)."""
    text = files_of(c)[c.file]
    assert _text_at(text, c.line, c.column).startswith(c.at)
    if c.at == "":
        assert c.column == len(text.splitlines()[c.line - 1]) + 1


@pytest.mark.parametrize("c", [_with_xfail(p, FIRST_DIAGNOSTIC_XFAIL) for p in CASES])
def test_first_diagnostic(c: Case, tmp_path: Path) -> None:
    files = files_of(c)
    write(tmp_path, files)
    with pytest.raises(RDDLError) as info:
        load(tmp_path)
    err = info.value
    expected_class = RDDLSyntaxError if c.kind == "syntax" else RDDLSemanticError
    assert isinstance(err, expected_class), type(err)
    assert err.diagnostics
    d = err.diagnostics[0]
    assert (Path(d.file).name, d.line, d.column, d.kind) == (c.file, c.line, c.column, c.kind), (
        d.render()
    )
    for part in c.message:
        assert part in d.message, d.render()
    if c.kind == "syntax":
        # parse() alone reports the same first error.
        with pytest.raises(RDDLSyntaxError) as pinfo:
            parse(files[c.file], c.file)
        pd = pinfo.value.diagnostics[0]
        assert (pd.line, pd.column) == (c.line, c.column), pd.render()


# Each case is one edit making one mistake: it should give one diagnostic,
# not follow-on errors (the checker means to suppress them: an unknown type
# is None) nor the same error twice.
ONE_DIAGNOSTIC_XFAIL = {
    "unknown-type-in-parameter-list": "follow-on type errors for arguments of the "
    "pvariable whose parameter type is unknown",
}
# An instance whose domain file does not parse is reported too (its own line
# in `rddl check`), naming that file: two diagnostics by design.
TWO_DIAGNOSTICS_BY_DESIGN = {"split-illegal-character-in-domain-file"}


def _case_id(c: Case) -> str:
    return next(p.id for p in CASES if p.values[0] is c)  # type: ignore[attr-defined]


@pytest.mark.parametrize("c", [_with_xfail(p, ONE_DIAGNOSTIC_XFAIL) for p in CASES])
def test_one_edit_one_diagnostic(c: Case, tmp_path: Path) -> None:
    write(tmp_path, files_of(c))
    with pytest.raises(RDDLError) as info:
        load(tmp_path)
    expected = 2 if _case_id(c) in TWO_DIAGNOSTICS_BY_DESIGN else 1
    assert len(info.value.diagnostics) == expected, info.value.render(show_source=False)
    if expected == 2:
        assert "has syntax errors" in info.value.diagnostics[1].message


# --------------------------------------------------- several errors at once


def _diag_keys(err: RDDLError) -> list[tuple[int, int, str]]:
    return [(d.line, d.column, d.kind) for d in err.diagnostics]


def test_two_semantic_errors_in_domain(tmp_path: Path) -> None:
    text = edit(
        BASE,
        (
            ("then ~on(?r)", "then ~onn(?r)"),
            ("[WATTS(?r) * on(?r)] - lit", "[WATS(?r) * on(?r)] - lit"),
        ),
    )
    write(tmp_path, {ONE: text})
    with pytest.raises(RDDLSemanticError) as info:
        load(tmp_path)
    assert _diag_keys(info.value) == [(19, 39, "unknown-name"), (23, 31, "unknown-name")]


def test_two_semantic_errors_in_instance(tmp_path: Path) -> None:
    text = edit(
        BASE,
        (
            ("IN(r1, h1);", "IN(r1, h7);"),
            ("on(r1) = true;", "on(r9) = true;"),
        ),
    )
    write(tmp_path, {ONE: text})
    with pytest.raises(RDDLSemanticError) as info:
        load(tmp_path)
    assert _diag_keys(info.value) == [(34, 9, "unknown-object"), (42, 9, "unknown-object")]


def test_domain_error_and_instance_error(tmp_path: Path) -> None:
    text = edit(
        BASE,
        (
            ("then ~on(?r)", "then ~onn(?r)"),
            ("on(r1) = true;", "on(r9) = true;"),
        ),
    )
    write(tmp_path, {ONE: text})
    with pytest.raises(RDDLSemanticError) as info:
        load(tmp_path)
    assert _diag_keys(info.value) == [(19, 39, "unknown-name"), (42, 9, "unknown-object")]


def test_syntax_errors_in_two_blocks(tmp_path: Path) -> None:
    text = edit(
        BASE,
        (
            ("if (lit > 1)", "if (lit # 1)"),
            ("    horizon = 10;\n", "    horizon = 10\n"),
        ),
    )
    write(tmp_path, {ONE: text})
    with pytest.raises(RDDLSyntaxError) as info:
        load(tmp_path)
    assert _diag_keys(info.value) == [(20, 25, "syntax"), (46, 5, "syntax")]
    assert "'#'" in info.value.diagnostics[0].message
    assert "';'" in info.value.diagnostics[1].message


def test_syntax_errors_in_two_files(tmp_path: Path) -> None:
    text = edit(
        BASE,
        (
            ("if (lit > 1)", "if (lit # 1)"),
            ("    horizon = 10;\n", "    horizon = 10\n"),
        ),
    )
    cut = text.index("non-fluents lights_nf {")
    write(tmp_path, {DOM: text[:cut], INST: text[cut:]})
    with pytest.raises(RDDLSyntaxError) as info:
        load(tmp_path)
    found = [
        (Path(d.file).name, d.line, d.column) for d in info.value.diagnostics if d.kind == "syntax"
    ]
    assert found == [(DOM, 20, 25), (INST, 21, 5)]


# ------------------------------------------------------------- render


@pytest.mark.parametrize(
    "edits, line, column, kind",
    [
        pytest.param((("if (lit > 1)", "if (lit # 1)"),), 20, 25, "syntax", id="syntax"),
        pytest.param((("[on(?r)];", "[on(?r) == WATTS(?r)];"),), 18, 39, "type", id="domain"),
        pytest.param(
            (("on(r1) = true;", "on(r9) = true;"),), 42, 9, "unknown-object", id="instance"
        ),
    ],
)
def test_render_shows_source_line_and_caret(
    tmp_path: Path, edits: tuple[tuple[str, str], ...], line: int, column: int, kind: str
) -> None:
    text = edit(BASE, edits)
    path = tmp_path / ONE
    path.write_text(text, encoding="utf-8")
    with pytest.raises(RDDLError) as info:
        load(tmp_path)
    rendered = info.value.render().splitlines()
    src = text.splitlines()[line - 1]
    assert rendered[0].startswith(f"{path}:{line}:{column}: {kind}: ")
    assert rendered[1] == "    " + src
    assert rendered[2] == "    " + " " * (column - 1) + "^"
    # Without the source: one line per diagnostic.
    assert info.value.render(show_source=False).splitlines()[0] == rendered[0]


# ----------------------------------------------------- random mutations

ALPHABET = "{}()[];:,.=<>~^|&+-*/$@?'_#\"\\ \n\tazAZ019é\x00"


def _mutate(seed: int) -> str:
    rng = random.Random(seed)
    pos = rng.randrange(len(BASE))
    if rng.random() < 0.5:
        return BASE[:pos] + BASE[pos + 1 :]
    return BASE[:pos] + rng.choice(ALPHABET) + BASE[pos:]


@pytest.mark.parametrize("seed", range(200))
def test_random_mutation_fails_cleanly(seed: int, tmp_path: Path) -> None:
    text = _mutate(seed)
    (tmp_path / ONE).write_text(text, encoding="utf-8")
    try:
        load(tmp_path)
    except RDDLError as err:
        n = len(text.splitlines()) + 1
        for d in err.diagnostics:
            assert 1 <= d.line <= n and d.column >= 1, d.render()
