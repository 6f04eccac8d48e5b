"""HTML that escapes everything it is not told is markup.

Every name that comes from the network or from files (client names,
instance names, fluents, reasons) is text: `h()` escapes every child and
attribute value that is not a `Markup`, and only `h()`, `page()` and the
chart functions make `Markup`. There is no way to pass a string through
unescaped but to wrap it in `Markup` by hand, which a review can find.
"""

from __future__ import annotations

import html as _html
import re
from collections.abc import Iterable, Mapping
from typing import Any
from urllib.parse import quote

STATIC = "/static"  # where the pages find live.js and style.css

_NAME = re.compile(r"^[a-z][a-z0-9-]*$")
_VOID = {"br", "hr", "img", "meta", "link", "input", "col", "source"}


class Markup(str):
    """A string that is HTML already (made by `h`, `page` or the charts)."""

    __slots__ = ()

    def __add__(self, other: str) -> Markup:
        return Markup(str(self) + str(esc(other)))


def esc(value: Any) -> Markup:
    """`value` as text in HTML (a `Markup` stays as it is); None is empty."""
    if isinstance(value, Markup):
        return value
    if value is None:
        return Markup("")
    if isinstance(value, float):
        value = fmt_number(value)
    return Markup(_html.escape(str(value), quote=True))


def fmt_number(x: float | int | None, digits: int = 4) -> str:
    """A number as a page shows it (`-`, an integer, or `digits` significant
    digits)."""
    if x is None:
        return "-"
    if isinstance(x, int):
        return str(x)
    if x != x:
        return "nan"
    if x == int(x) and abs(x) < 1e15:
        return str(int(x))
    return f"{x:.{digits}g}"


def h(tag: str, *children: Any, **attrs: Any) -> Markup:
    """An element: `h("td", name, class_="c", data_field="client")`.

    Children are escaped unless `Markup` (lists and tuples are flattened,
    None skipped); attribute values are always escaped; `class_` is
    `class`, `data_x` is `data-x`; an attribute True is present without a
    value, False or None is left out."""
    if not _NAME.match(tag):
        raise ValueError(f"not a tag name: {tag!r}")
    parts = [f"<{tag}"]
    for key, value in attrs.items():
        name = key.rstrip("_").replace("_", "-")
        if not _NAME.match(name):
            raise ValueError(f"not an attribute name: {key!r}")
        if value is None or value is False:
            continue
        if value is True:
            parts.append(f" {name}")
        else:
            parts.append(f' {name}="{_html.escape(str(value), quote=True)}"')
    parts.append(">")
    if tag in _VOID:
        if children:
            raise ValueError(f"<{tag}> has no children")
        return Markup("".join(parts))
    parts.extend(_children(children))
    parts.append(f"</{tag}>")
    return Markup("".join(parts))


def _children(children: Iterable[Any]) -> Iterable[str]:
    for child in children:
        if child is None:
            continue
        if isinstance(child, list | tuple):
            yield from _children(child)
        else:
            yield esc(child)


def join(items: Iterable[Any]) -> Markup:
    """Fragments one after the other (text escaped)."""
    return Markup("".join(esc(x) for x in items))


def page(
    title: str,
    *body: Any,
    events: str | None = None,
    nav: Mapping[str, str] | None = None,
    scripts: Iterable[str] = ("live.js",),
    layout: str | None = None,
) -> Markup:
    """A whole document: `title`, the stylesheet and scripts from the
    package's static folder, `body`. With `events` (a path such as
    `/events`), live.js follows that event stream (see docs/web.md for the
    events it applies). `nav` maps link text to paths for the top bar.
    `layout` names what the page's tables were built for (their columns):
    a `layout` field that says otherwise makes live.js load the page again."""
    links = [h("a", text, href=href) for text, href in (nav or {}).items()]
    return Markup(
        "<!DOCTYPE html>\n"
        + h(
            "html",
            h(
                "head",
                h("meta", charset="utf-8"),
                h("meta", name="viewport", content="width=device-width, initial-scale=1"),
                h("title", title),
                h("link", rel="stylesheet", href=f"{STATIC}/style.css"),
                h("link", rel="icon", href=f"{STATIC}/icon.svg", type="image/svg+xml"),
                [h("script", src=f"{STATIC}/{name}", defer=True) for name in scripts],
            ),
            h(
                "body",
                h("nav", links, h("span", "live", class_="conn", id="conn")) if nav else None,
                h("h1", title),
                *body,
                data_events=events,
                data_layout=layout,
            ),
            lang="en",
        )
        + "\n"
    )


def live_table(
    table: str,
    columns: Iterable[tuple[str, str]],
    rows: Iterable[tuple[str, Mapping[str, Any]]] = (),
    *,
    links: Mapping[str, str] | None = None,
    charts: Mapping[str, tuple[str, str]] | None = None,
    limit: int | None = None,
    newest_first: bool = False,
    state_field: str | None = "state",
) -> Markup:
    """A table live.js keeps up to date from `row` events (see
    `row_event`): `columns` are (field, heading) pairs; `rows` the
    (key, cells) already known; `links` maps a field to a path with `{key}`
    (the cell becomes a link); `charts` maps a field to (path with `{key}`,
    the field whose change redraws it) for an <img> of an SVG chart;
    `limit` keeps only that many rows (the oldest go)."""
    cols = list(columns)
    links = dict(links or {})
    charts = dict(charts or {})

    def row(key: str | None, cells: Mapping[str, Any]) -> Markup:
        tds = []
        for field, _ in cols:
            value = cells.get(field) if key is not None else None
            if field in charts:
                path, version = charts[field]
                src = path.replace("{key}", quote(key, safe="")) if key is not None else None
                if src is not None and cells.get(version) is not None:
                    src += f"?v={cells.get(version)}"
                tds.append(
                    h(
                        "td",
                        h(
                            "img",
                            src=src,
                            alt="chart",
                            class_="spark",
                            data_chart=path,
                            data_version=version,
                        ),
                    )
                )
            elif field in links:
                path = links[field]
                tds.append(
                    h(
                        "td",
                        h(
                            "a",
                            _cell(value),
                            href=path.replace("{key}", quote(key, safe=""))
                            if key is not None
                            else None,
                            data_field=field,
                            data_href=path,
                        ),
                    )
                )
            elif isinstance(value, Mapping):
                tds.append(_rich_cell(field, value))
            else:
                tds.append(h("td", _cell(value), data_field=field))
        state = cells.get(state_field) if (state_field and key is not None) else None
        return h("tr", tds, data_key=key, data_state=state)

    body = [row(key, cells) for key, cells in rows]
    if newest_first:
        body.reverse()
    return h(
        "table",
        h("thead", h("tr", [h("th", heading) for _, heading in cols])),
        h(
            "tbody",
            body,
            data_table=table,
            data_limit=limit,
            data_order="newest-first" if newest_first else None,
            data_state_field=state_field,
        ),
        h("template", row(None, {}), data_row_for=table),
        class_="live",
    )


def cell(text: Any, state: str | None = None, href: str | None = None) -> dict[str, Any]:
    """A table cell with its own state (it colours the cell, as a row's `state`
    colours the row) and a link (a path of this view: it must start with one `/`)."""
    if href is not None and not _local_path(href):
        raise ValueError(f"not a path of this view: {href!r}")
    out: dict[str, Any] = {"text": fmt_number(text) if isinstance(text, float) else text}
    if state is not None:
        out["state"] = state
    if href is not None:
        out["href"] = href
    return out


def _local_path(href: Any) -> bool:
    return isinstance(href, str) and href.startswith("/") and not href.startswith("//")


def _rich_cell(field: str, value: Mapping[str, Any]) -> Markup:
    text = _cell(value.get("text"))
    href = value.get("href")
    inner = h("a", text, href=href) if _local_path(href) else text
    return h("td", inner, data_field=field, data_state=value.get("state"))


def _cell(value: Any) -> Markup:
    if isinstance(value, float):
        return esc(fmt_number(value))
    return esc(value)


def field(name: str, value: Any = None, tag: str = "span") -> Markup:
    """A value outside tables that live.js updates from `fields` events."""
    return h(tag, _cell(value), data_page_field=name)


# -- the events live.js applies (built here so a page and its tests agree)


def row_event(table: str, key: str | int, cells: Mapping[str, Any]) -> dict[str, Any]:
    """Set the cells of the row `key` of `table` (added if new)."""
    return {"type": "rows", "rows": [{"table": table, "key": str(key), "cells": _json(cells)}]}


def rows_event(
    rows: Iterable[tuple[str, str | int, Mapping[str, Any]]], *, reset: bool = False
) -> dict[str, Any]:
    """Several rows at once ((table, key, cells) each); with `reset`, the
    tables named are emptied first (a snapshot)."""
    return {
        "type": "rows",
        "reset": reset,
        "rows": [{"table": t, "key": str(k), "cells": _json(c)} for t, k, c in rows],
    }


def remove_event(table: str, key: str | int) -> dict[str, Any]:
    """Remove the row `key` of `table`."""
    return {"type": "rows", "rows": [{"table": table, "key": str(key), "remove": True}]}


def fields_event(fields: Mapping[str, Any]) -> dict[str, Any]:
    """Set the values made by `field()`."""
    return {"type": "fields", "fields": _json(fields)}


def _json(cells: Mapping[str, Any]) -> dict[str, Any]:
    # numbers are formatted as the server renders them, so a live update
    # and a reload show the same text
    return {k: (fmt_number(v) if isinstance(v, float) else v) for k, v in cells.items()}


__all__ = [
    "STATIC",
    "Markup",
    "esc",
    "field",
    "fields_event",
    "fmt_number",
    "h",
    "join",
    "live_table",
    "page",
    "cell",
    "remove_event",
    "row_event",
    "rows_event",
]
