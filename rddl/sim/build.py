"""Writing a simulator's generated functions.

Owns what the generated code of a `Simulator` is made of beyond single
expressions. `build_step` writes the step, for small batches, for large
ones or for exactly one state: the constraint checks, every cpf in
`order._order_cpfs`'s order, the reward, the state invariants and the
termination, and the return of the next state, reward, observations and
done flags, batch first. `build_constraints` writes the constraint checks
alone (the mask of the legal states, or the raise of the first violation).
`_bind` says what a pvariable name means in the function being written
(the non-fluents' constants; the state `S` and actions `A`, read batch
last) and `_output` makes each returned value an array of its own.

May call the compiler (`compiler._Compiler`, as `sim._compiler`) and `code`;
`simulator` calls it once per function, when the function is first needed.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from ..model import OBSERV, STATE
from .code import _DTYPE_CODE, _batch_first, _batch_last, _last_shape_code, _Node
from .parts import SimulatorParts


def _bind(sim: SimulatorParts, state: Mapping[str, _Node] | None = None) -> None:
    """What pvariable names mean in the function being written: the
    non-fluents' values, the state (`S`, or the given next state) and
    the actions (`A`)."""
    c = sim._compiler
    c.context += 1
    c.values = dict(sim._nf_nodes)

    # arrays come batch first (B, *params); the generated code works
    # batch last (*params, B): a view, and no copy where the array was
    # made by a step (its memory is batch last)
    # (for large batches made contiguous: operations on arrays of mixed
    # layouts are several times slower, and a copy costs about one)
    def read(source: str, arity: int) -> str:
        text = source + _batch_last(arity + 1)
        return f"_contiguous({text})" if c.large and arity else text

    for i, p in enumerate(sim.state_fluents):
        if state is not None:
            c.values[p.name] = (state[p.name], None)
        else:
            node = _Node(f"s{i}", (*c.shape_of(p), 1), np.dtype(sim._dtype(p)), p.range, True)
            c.values[p.name] = (node, read(f"S[{p.name!r}]", p.arity))
    for i, p in enumerate(sim.action_fluents):
        node = _Node(f"a{i}", (*c.shape_of(p), 1), np.dtype(sim._dtype(p)), p.range, True)
        source = read(f"A[{p.name!r}]", p.arity)
        if c.large and p.arity and not sim._defaults[p.name].any():
            # (an action left at its default everywhere, as most are in
            # most steps, is not worth a transposing copy)
            source = f"_action_in(A[{p.name!r}], {(*range(1, p.arity + 1), 0)})"
        c.values[p.name] = (node, source)


def _output(
    sim: SimulatorParts, node: _Node, shape: tuple[int, ...], dtype: Any, used: set[str]
) -> _Node:
    """`node` as an array of its own, shaped (*shape, B): the value
    itself where this step allocated it and nothing else returns it,
    else a copy."""
    c = sim._compiler
    dtype = np.dtype(dtype)
    full = (*shape, 1)
    if (
        node.batched
        and node.shape == full
        and node.dtype == dtype
        and node.owner
        and node.owner not in used
    ):
        used.add(node.owner)
        if not c.large:
            return node
        # batch last in memory too (a copy only where it is not)
        name = c.code.temp()
        c.code.emit(f"{name} = _contiguous({node.code})")
        return _Node(name, full, dtype, node.rtype, True, owner=node.owner)
    name = c.code.temp()
    if node.batched and node.shape == full:
        order = ", order='C'" if c.large else ""
        c.code.emit(f"{name} = {node.code}.astype({_DTYPE_CODE[dtype]}{order})")
    else:
        c.code.emit(f"{name} = _empty({_last_shape_code(shape)}, {_DTYPE_CODE[dtype]})")
        c.code.emit(f"{name}[...] = {node.code}")
    used.add(name)
    return _Node(name, full, dtype, node.rtype, True, owner=name)


def _emit_constraints(sim: SimulatorParts) -> None:
    """Statements that raise `SimulationError` for the first violated
    constraint: max-nondef-actions, then the preconditions in order."""
    c = sim._compiler
    limit = sim.model.max_nondef_actions
    if limit is not None and sim.action_fluents:
        terms = []
        for p in sim.action_fluents:
            a = c.ref(p, False)
            d = sim._defaults[p.name]
            if p.range == "bool" and not d.any():
                terms.append(f"_cnz({a.code})")
            else:
                terms.append(f"_cnz(_ne({a.code}, {c.global_name(d[..., None])}))")
        # the total over the batch bounds each state's count
        with c.code.block(f"if {' + '.join(terms)} > {limit}:"):
            c.fail(sim._fail_nondef, "A", "B")
    for k, expr in enumerate(sim._preconditions):
        holds = c.numeric(expr, ())
        if holds.value is not None:
            if not np.asarray(holds.value, dtype=bool).all():
                c.fail(sim._fail_precondition, str(k), holds.code, "A", "B")
            continue
        with c.code.block(f"if _cnz({holds.code}) != {holds.code}.size:"):
            c.fail(sim._fail_precondition, str(k), holds.code, "A", "B")


def build_step(sim: SimulatorParts, large: bool, one: bool = False) -> Callable[..., Any]:
    c = sim._compiler
    model = sim.model
    name = "_step_large" if large else "_step_one" if one else "_step"
    code = c.begin(name, "S, A, B, rng, check", large, one)
    _bind(sim)
    if sim._preconditions or model.max_nondef_actions is not None:
        with code.block("if check:"):
            _emit_constraints(sim)
    used: set[str] = set()
    nxt: dict[str, _Node] = {}
    obs: dict[str, _Node] = {}
    for key in sim._cpf_order:
        p = model.pvariables[key.rstrip("'")]
        cp = model.cpfs[p.name]
        scope = tuple(zip(cp.params, p.params, strict=True))
        node = c.compile(cp.expr, scope, p.range)
        shape = c.shape_of(p)
        dtype = np.dtype(sim._dtype(p))
        if p.kind == STATE:
            node = nxt[p.name] = _output(sim, node, shape, dtype, used)
            c.values[key] = (node, None)
        elif p.kind == OBSERV:
            node = obs[p.name] = _output(sim, node, shape, dtype, used)
            c.values[p.name] = (node, None)
        else:
            # an intermediate value: its type, over every grounding
            node = c.cast(node, dtype)
            if node.shape[:-1] != shape:
                dims = ", ".join([*map(str, shape), "{0}.shape[-1]"])
                node = c.op(f"_broadcast_to({{0}}, ({dims},))", [node], p.range, view=True)
            c.values[p.name] = (node, None)
    if model.reward is not None:
        reward = _output(sim, c.numeric(model.reward, ()), (), np.float64, used).code
    else:
        reward = "_zeros(B)"
    _bind(sim, {p.name: nxt[p.name] for p in sim.state_fluents})
    if sim._invariants:
        with code.block("if check:"):
            for k, expr in enumerate(sim._invariants):
                holds = c.numeric(expr, ())
                if holds.value is not None:
                    if not np.asarray(holds.value, dtype=bool).all():
                        c.fail(sim._fail_invariant, str(k), holds.code, "B")
                    continue
                with code.block(f"if _cnz({holds.code}) != {holds.code}.size:"):
                    c.fail(sim._fail_invariant, str(k), holds.code, "B")
    code.emit("done = _zeros(B, _bool)")
    for expr in sim._terminations:
        holds = c.numeric(expr, ())
        code.emit(f"_lor(done, {holds.code}, out=done)")
    # returned batch first: views of the batch-last arrays
    states = (
        "{"
        + ", ".join(
            f"{p.name!r}: {nxt[p.name].code}{_batch_first(p.arity + 1)}" for p in sim.state_fluents
        )
        + "}"
    )
    observed = "None"
    if sim.observ_fluents:
        pv = model.pvariables
        observed = (
            "{"
            + ", ".join(f"{k!r}: {v.code}{_batch_first(pv[k].arity + 1)}" for k, v in obs.items())
            + "}"
        )
    code.emit(f"return {states}, {reward}, {observed}, done")
    return c.build(code)


def build_constraints(
    sim: SimulatorParts, name: str, explain: bool, large: bool = False
) -> Callable[..., Any]:
    """`explain`: a function that raises for the first violated
    constraint (max-nondef-actions included); else one that returns
    the mask of the states where every precondition holds."""
    c = sim._compiler
    code = c.begin(name, "S, A, B", large)
    _bind(sim)
    if explain:
        _emit_constraints(sim)
        code.emit("return None")
        return c.build(code)
    code.emit("ok = np.ones(B, _bool)")
    for expr in sim._preconditions:
        holds = c.numeric(expr, ())
        code.emit(f"_land(ok, {holds.code}, out=ok)")
    code.emit("return ok")
    return c.build(code)
