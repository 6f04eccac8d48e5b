"""mcts's options are defined once (planners/mcts/options.py's TABLE): the help
`--planner-option` lists, the parser's defaults and docs/planners.md's two option tables
(public and experimental) are all derived from or checked against it."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from ippc.planners import PlannerError, make_planner
from ippc.planners.mcts import MCTSPlanner
from ippc.planners.mcts.options import BY_NAME, EXPERIMENTAL, PUBLIC, TABLE

DOCS = Path(__file__).resolve().parents[2] / "docs" / "planners.md"


def _doc_tables() -> list[dict[str, str]]:
    """The two option tables of the mcts section: [{option: default}, ...]."""
    text = DOCS.read_text(encoding="utf-8")
    start = text.index("**Options** (`--planner-option KEY=VALUE`), each defined once")
    tables: list[dict[str, str]] = []
    current: dict[str, str] | None = None
    for line in text[start:].splitlines():
        m = re.match(r"\| `([a-z_]+)` \| ([^|]*) \|", line)
        if m:
            if current is None:
                current = {}
                tables.append(current)
            current[m.group(1)] = m.group(2).strip()
        elif current is not None and not line.startswith("|"):
            current = None
            if len(tables) == 2:
                break
    return tables


def test_at_most_about_ten_public_options() -> None:
    assert len(PUBLIC) <= 12
    assert set(PUBLIC) | set(EXPERIMENTAL) == set(MCTSPlanner.options)
    assert not set(PUBLIC) & set(EXPERIMENTAL)


def test_the_docs_tables_are_the_table() -> None:
    public, experimental = _doc_tables()
    assert list(public) == list(PUBLIC)
    assert list(experimental) == list(EXPERIMENTAL)
    for name, shown in {**public, **experimental}.items():
        option = BY_NAME[name]
        if option.default_text is not None:
            assert shown == option.default_text, name
        elif isinstance(option.default, bool):
            assert shown == ("yes" if option.default else "no"), name
        else:
            assert shown.strip("`") == str(option.default), name


def test_the_help_and_the_parser_share_each_default() -> None:
    settings = make_planner("mcts", {}).settings
    for option in TABLE:
        assert MCTSPlanner.options[option.name].startswith(option.help), option.name
        assert "(default " in MCTSPlanner.options[option.name]
        if option.name == "heuristic":
            assert settings.heuristic == "ids"  # engine thts, the default
        elif hasattr(settings, option.name):
            assert getattr(settings, option.name) == option.default, option.name
    # the one default that depends on another option
    assert make_planner("mcts", {"engine": "wave"}).settings.heuristic == "rollout"


@pytest.mark.parametrize(
    "options,named",
    [
        ({"heuristic": "greedy"}, "heuristic"),
        ({"compiled": "maybe"}, "compiled"),
        ({"max_nodes": "0"}, "max_nodes"),
        ({"exploration": "-1"}, "exploration"),
        ({"prune_useless": "perhaps"}, "prune_useless"),
    ],
)
def test_a_bad_value_names_its_option(options: dict[str, str], named: str) -> None:
    with pytest.raises(PlannerError, match=named):
        make_planner("mcts", options)


def test_compiled_takes_the_usual_words_for_yes_and_no() -> None:
    assert make_planner("mcts", {"compiled": "off"}).settings.compiled == "no"
    assert make_planner("mcts", {"compiled": "true"}).settings.compiled == "yes"
