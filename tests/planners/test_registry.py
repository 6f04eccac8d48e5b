"""Planner lookup by name (entry points, built-ins) and option parsing."""

from __future__ import annotations

import importlib.metadata
from pathlib import Path
from typing import Any, ClassVar

import pytest
from ippc.planners import (
    ExternalPlanner,
    NoopPlanner,
    Observation,
    Planner,
    PlannerError,
    ProstPlanner,
    RandomPlanner,
    WireFluent,
    find_planner,
    make_planner,
    planner_names,
)


class ThirdPartyPlanner(Planner):
    """What a plug-in package would declare under `ippc.planners`."""

    name: ClassVar[str] = "third"
    options: ClassVar[dict[str, str]] = {
        "depth": "an integer",
        "rate": "a number",
        "verbose": "a flag",
        "model_file": "a path",
        "label": "text",
    }

    def act(self, obs: Observation) -> list[WireFluent]:
        return []


NOT_A_PLANNER = object()


def entry_points_with(*extra: tuple[str, str], keep_builtins: bool = True) -> Any:
    """A stand-in for importlib.metadata.entry_points(group=...)."""
    real = list(importlib.metadata.entry_points(group="ippc.planners")) if keep_builtins else []
    fake = [importlib.metadata.EntryPoint(name=n, value=v, group="ippc.planners") for n, v in extra]

    def entry_points(**kw: Any) -> list[importlib.metadata.EntryPoint]:
        assert kw == {"group": "ippc.planners"}
        return real + fake

    return entry_points


def test_builtins_by_name() -> None:
    assert {"noop", "random", "prost"} <= set(planner_names())
    assert find_planner("noop") is NoopPlanner
    assert find_planner("random") is RandomPlanner
    assert find_planner("prost") is ProstPlanner
    assert issubclass(find_planner("prost"), ExternalPlanner) and ProstPlanner.external
    assert not RandomPlanner.external
    planner = make_planner("random", {"seed": "3"})
    assert isinstance(planner, RandomPlanner) and planner.seed == 3


def test_unknown_name_lists_the_known_ones() -> None:
    with pytest.raises(
        PlannerError,
        match=r"unknown planner 'nosuch' \(known planners: exact, fast-downward, mcts, mpc, noop, prost, random",
    ):
        find_planner("nosuch")


def test_third_party_entry_point(monkeypatch: pytest.MonkeyPatch) -> None:
    target = f"{__name__}:ThirdPartyPlanner"
    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points_with(("third", target)))
    assert "third" in planner_names()
    assert find_planner("third") is ThirdPartyPlanner
    planner = make_planner("third", {"depth": "4", "verbose": "yes"})
    assert isinstance(planner, ThirdPartyPlanner)
    assert planner.int_option("depth") == 4 and planner.bool_option("verbose", False) is True


def test_builtins_without_package_metadata(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points_with(keep_builtins=False))
    assert planner_names() == [
        "exact",
        "mcts",
        "mpc",
        "noop",
        "prost",
        "random",
        "replan",
        "uniform",
    ]
    assert find_planner("random") is RandomPlanner

    def broken(**kw: Any) -> Any:
        raise RuntimeError("bad metadata")

    monkeypatch.setattr(importlib.metadata, "entry_points", broken)
    assert find_planner("noop") is NoopPlanner


def test_broken_entry_points(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(
        importlib.metadata,
        "entry_points",
        entry_points_with(
            ("gone", "no_such_module_xyz:Planner"), ("odd", f"{__name__}:NOT_A_PLANNER")
        ),
    )
    with pytest.raises(
        PlannerError,
        match=r"planner 'gone': entry point 'no_such_module_xyz:Planner' cannot be loaded: ModuleNotFoundError",
    ):
        find_planner("gone")
    with pytest.raises(
        PlannerError, match=r"planner 'odd' \(entry point '.*:NOT_A_PLANNER'\) is not a Planner"
    ):
        find_planner("odd")


def test_duplicate_name_prefers_ippcs_own(monkeypatch: pytest.MonkeyPatch) -> None:
    target = f"{__name__}:ThirdPartyPlanner"
    monkeypatch.setattr(
        importlib.metadata, "entry_points", entry_points_with(("noop", target), ("x", target))
    )
    assert find_planner("noop") is NoopPlanner
    assert planner_names().count("noop") == 1


# ----------------------------------------------------------------- options


def test_option_readers() -> None:
    p = ThirdPartyPlanner(
        **{
            "depth": " 12",
            "rate": "0.5",
            "verbose": "Off",
            "model-file": "~/m.rddl",
            "label": "a b",
        }
    )
    assert p.option_values["model_file"] == "~/m.rddl"  # '-' and '_' are one
    assert p.int_option("depth") == 12
    assert p.float_option("rate") == 0.5
    assert p.bool_option("verbose", True) is False
    assert p.path_option("model_file") == Path("~/m.rddl").expanduser()
    assert p.str_option("label") == "a b"
    empty = ThirdPartyPlanner()
    assert empty.int_option("depth", 3) == 3 and empty.float_option("rate") is None
    assert empty.bool_option("verbose", True) is True and empty.path_option("model_file") is None
    with pytest.raises(KeyError, match="does not declare"):
        empty.int_option("dpeth")  # the planner's own typo


@pytest.mark.parametrize(
    "key,value,reader,message",
    [
        ("depth", "three", "int_option", "must be an integer, got 'three'"),
        ("depth", "1.5", "int_option", "must be an integer"),
        ("depth", "-1", "int_option", "must be an integer >= 0"),
        ("rate", "fast", "float_option", "must be a number, got 'fast'"),
        ("rate", "nan", "float_option", "must be a number"),
        ("verbose", "maybe", "bool_option", "must be one of true/false, yes/no, on/off, 1/0"),
        ("model_file", " ", "path_option", "must be a path"),
    ],
)
def test_option_errors(key: str, value: str, reader: str, message: str) -> None:
    p = ThirdPartyPlanner(**{key: value})
    args: dict[str, Any] = {"minimum": 0} if reader == "int_option" else {}
    if reader == "bool_option":
        args = {"default": False}
    with pytest.raises(PlannerError, match=f"planner 'third': option '{key}' {message}"):
        getattr(p, reader)(key, **args)


def test_unknown_and_non_string_options() -> None:
    with pytest.raises(
        PlannerError,
        match=r"planner 'third' has no option 'dept' \(valid options: depth, label, model_file, rate, verbose\)",
    ):
        ThirdPartyPlanner(dept="1")
    with pytest.raises(PlannerError, match="option 'depth' must be given as a string, got int"):
        ThirdPartyPlanner(depth=3)  # type: ignore[arg-type]
