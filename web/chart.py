"""Small SVG charts drawn by the server (no script, no library in the page).

A page shows them as `<img src=...svg>`: an SVG loaded as an image runs no
script and fetches nothing, and every label in it is escaped here. live.js
reloads the image when the number it depends on changes (see
`html.live_table`'s `charts`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from .html import Markup, esc, fmt_number

# colour-blind-safe categorical colours (Okabe and Ito)
PALETTE = ("#0072b2", "#e69f00", "#009e73", "#cc79a7", "#56b4e9", "#d55e00", "#f0e442", "#000000")


def _finite(values: Sequence[float | None]) -> list[float]:
    return [v for v in values if v is not None and math.isfinite(v)]


def _range(values: list[float]) -> tuple[float, float]:
    if not values:
        return 0.0, 1.0
    lo, hi = min(values), max(values)
    if lo == hi:
        pad = abs(lo) * 0.1 or 1.0
        return lo - pad, hi + pad
    return lo, hi


def _svg(width: int, height: int, label: str, *body: str) -> Markup:
    return Markup(
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}"'
        f' viewBox="0 0 {width} {height}" role="img" aria-label="{esc(label)}">'
        f"<title>{esc(label)}</title>" + "".join(body) + "</svg>\n"
    )


def sparkline(
    values: Sequence[float | None],
    *,
    width: int = 180,
    height: int = 40,
    label: str = "",
    x_start: int = 1,
) -> Markup:
    """A small line of `values` (one point each, e.g. a session's round rewards)
    with its scale: the highest and lowest value at the left, the first and last
    index (from `x_start`) below, and a dot at the last one; empty when there is
    nothing to draw."""
    pts = [(i, v) for i, v in enumerate(values) if v is not None and math.isfinite(v)]
    if not pts:
        return _svg(width, height, label or "no data yet")
    lo, hi = _range([v for _, v in pts])
    n = max(len(values) - 1, 1)
    left, right, top, bottom = 44, 4, 4, 12
    plot_w, plot_h = width - left - right, height - top - bottom

    def xy(i: int, v: float) -> tuple[float, float]:
        x = left + plot_w * (i / n if len(values) > 1 else 0.5)
        y = top + plot_h - plot_h * (v - lo) / (hi - lo)
        return round(x, 1), round(y, 1)

    coords = [xy(i, v) for i, v in pts]
    path = " ".join(f"{x},{y}" for x, y in coords)
    lx, ly = coords[-1]
    font = 'font-family="sans-serif" font-size="9" fill="#555"'
    base = top + plot_h
    scale = [
        f'<line x1="{left - 2}" x2="{left - 2}" y1="{top}" y2="{base}" stroke="#aaa"/>',
        f'<line x1="{left - 2}" x2="{width - right}" y1="{base}" y2="{base}" stroke="#aaa"/>',
        f'<text x="{left - 5}" y="{top + 7}" text-anchor="end" {font}>{esc(fmt_number(hi, 3))}</text>',
        f'<text x="{left - 5}" y="{base}" text-anchor="end" {font}>{esc(fmt_number(lo, 3))}</text>',
        f'<text x="{left}" y="{height - 1}" {font}>{x_start}</text>',
    ]
    if len(values) > 1:
        scale.append(
            f'<text x="{width - right}" y="{height - 1}" text-anchor="end" {font}>'
            f"{x_start + len(values) - 1}</text>"
        )
    return _svg(
        width,
        height,
        label or f"{len(pts)} values, last {fmt_number(pts[-1][1])}",
        *scale,
        f'<polyline points="{path}" fill="none" stroke="{PALETTE[0]}" stroke-width="1.5"/>',
        f'<circle cx="{lx}" cy="{ly}" r="2.5" fill="{PALETTE[5]}"/>',
    )


def line_chart(
    series: Mapping[str, Sequence[float | None]],
    *,
    title: str = "",
    x_label: str = "round",
    y_label: str = "reward",
    width: int = 640,
    height: int = 260,
    x_start: int = 1,
) -> Markup:
    """Lines of several series against their index (`x_start` for the
    first), with axes, ticks and a legend; names are escaped."""
    left, right, top, bottom = 64, 16, 28 if title else 12, 40
    legend_h = 16 * min(len(series), 8)
    plot_w = width - left - right
    plot_h = height - top - bottom
    total_h = height + legend_h
    values = [v for vs in series.values() for v in _finite(vs)]
    lo, hi = _range(values)
    n = max((len(vs) for vs in series.values()), default=0)
    span = max(n - 1, 1)

    def x(i: int) -> float:
        return round(left + plot_w * (i / span if n > 1 else 0.5), 1)

    def y(v: float) -> float:
        return round(top + plot_h - plot_h * (v - lo) / (hi - lo), 1)

    parts: list[str] = []
    if title:
        parts.append(
            f'<text x="{left}" y="16" font-family="sans-serif" font-size="13">{esc(title)}</text>'
        )
    # axes and ticks
    parts.append(
        f'<rect x="{left}" y="{top}" width="{plot_w}" height="{plot_h}" fill="none" stroke="#888"/>'
    )
    for k in range(5):
        v = lo + (hi - lo) * k / 4
        yy = y(v)
        parts.append(
            f'<line x1="{left}" x2="{left + plot_w}" y1="{yy}" y2="{yy}" stroke="#ddd"/>'
            f'<text x="{left - 4}" y="{yy + 4}" text-anchor="end" font-family="sans-serif"'
            f' font-size="11">{esc(fmt_number(v, 3))}</text>'
        )
    for i in sorted({0, n // 2, n - 1} if n > 0 else set()):
        parts.append(
            f'<text x="{x(i)}" y="{top + plot_h + 16}" text-anchor="middle" font-family="sans-serif"'
            f' font-size="11">{i + x_start}</text>'
        )
    parts.append(
        f'<text x="{left + plot_w / 2}" y="{top + plot_h + 32}" text-anchor="middle"'
        f' font-family="sans-serif" font-size="12">{esc(x_label)}</text>'
        f'<text x="14" y="{top + plot_h / 2}" text-anchor="middle" font-family="sans-serif"'
        f' font-size="12" transform="rotate(-90 14 {top + plot_h / 2})">{esc(y_label)}</text>'
    )
    if not values:
        parts.append(
            f'<text x="{left + plot_w / 2}" y="{top + plot_h / 2}" text-anchor="middle"'
            f' font-family="sans-serif" font-size="12" fill="#666">no data yet</text>'
        )
    for k, (name, vs) in enumerate(series.items()):
        colour = PALETTE[k % len(PALETTE)]
        pts = [(x(i), y(v)) for i, v in enumerate(vs) if v is not None and math.isfinite(v)]
        if len(pts) > 1:
            parts.append(
                f'<polyline points="{" ".join(f"{a},{b}" for a, b in pts)}" fill="none"'
                f' stroke="{colour}" stroke-width="1.5"/>'
            )
        for a, b in pts if len(pts) <= 60 else pts[-1:]:
            parts.append(f'<circle cx="{a}" cy="{b}" r="2.5" fill="{colour}"/>')
        if k < 8:
            ly = height + 16 * k + 4
            parts.append(
                f'<rect x="{left}" y="{ly}" width="10" height="10" fill="{colour}"/>'
                f'<text x="{left + 16}" y="{ly + 9}" font-family="sans-serif" font-size="11">'
                f"{esc(name)}</text>"
            )
    if len(series) > 8:
        parts.append(
            f'<text x="{left + 200}" y="{height + 13}" font-family="sans-serif" font-size="11">'
            f"(and {len(series) - 8} more)</text>"
        )
    return _svg(width, total_h, title or f"{y_label} per {x_label}", *parts)


def bar_chart(
    groups: Mapping[str, Mapping[str, float | None]],
    series: Sequence[str],
    *,
    title: str,
    y_label: str,
    y_max: float | None = None,
    width: int = 760,
    height: int = 300,
) -> Markup:
    """Grouped bars: one group per key of `groups` (instances, domains), one bar per
    name of `series` (planners) in each; every label escaped."""
    left, right, top, bottom = 64, 16, 28, 110
    legend_h = 16 * min(len(series), 8)
    plot_w, plot_h = width - left - right, height - top - bottom
    values = [v for g in groups.values() for v in g.values() if v is not None and math.isfinite(v)]
    hi = y_max if y_max is not None else max([0.0, *values]) or 1.0
    lo = min([0.0, *values])
    if hi == lo:
        hi = lo + 1.0
    names = list(groups)
    slot = plot_w / max(1, len(names))
    bar = slot * 0.8 / max(1, len(series))

    def y(v: float) -> float:
        return round(top + plot_h - plot_h * (v - lo) / (hi - lo), 1)

    parts = [
        f'<text x="{left}" y="16" font-family="sans-serif" font-size="13">{esc(title)}</text>',
        f'<rect x="{left}" y="{top}" width="{plot_w}" height="{plot_h}" fill="none" stroke="#888"/>',
    ]
    for k in range(5):
        v = lo + (hi - lo) * k / 4
        parts.append(
            f'<line x1="{left}" x2="{left + plot_w}" y1="{y(v)}" y2="{y(v)}" stroke="#ddd"/>'
            f'<text x="{left - 4}" y="{y(v) + 4}" text-anchor="end" font-family="sans-serif"'
            f' font-size="11">{esc(fmt_number(v, 3))}</text>'
        )
    parts.append(
        f'<text x="14" y="{top + plot_h / 2}" text-anchor="middle" font-family="sans-serif"'
        f' font-size="12" transform="rotate(-90 14 {top + plot_h / 2})">{esc(y_label)}</text>'
    )
    if not names:
        parts.append(
            f'<text x="{left + plot_w / 2}" y="{top + plot_h / 2}" text-anchor="middle"'
            f' font-family="sans-serif" font-size="12" fill="#666">no data yet</text>'
        )
    for i, name in enumerate(names):
        x0 = left + slot * i + slot * 0.1
        for k, s in enumerate(series):
            value = groups[name].get(s)
            if value is None or not math.isfinite(value):
                continue
            y0, y1 = sorted((y(value), y(max(lo, 0.0))))
            parts.append(
                f'<rect x="{round(x0 + bar * k, 1)}" y="{y0}" width="{round(bar, 1)}"'
                f' height="{round(max(y1 - y0, 0.5), 1)}" fill="{PALETTE[k % len(PALETTE)]}">'
                f"<title>{esc(name)}: {esc(s)} {esc(fmt_number(value))}</title></rect>"
            )
        cx = round(left + slot * (i + 0.5), 1)
        cy = top + plot_h + 8
        label = name if len(name) <= 28 else name[:27] + "\u2026"
        parts.append(
            f'<text x="{cx}" y="{cy}" text-anchor="end" font-family="sans-serif" font-size="10"'
            f' transform="rotate(-50 {cx} {cy})">{esc(label)}</text>'
        )
    for k, s in enumerate(series[:8]):
        ly = height + 16 * k + 4
        parts.append(
            f'<rect x="{left}" y="{ly}" width="10" height="10" fill="{PALETTE[k % len(PALETTE)]}"/>'
            f'<text x="{left + 16}" y="{ly + 9}" font-family="sans-serif" font-size="11">'
            f"{esc(s)}</text>"
        )
    total = height + legend_h
    return Markup(
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{total}"'
        f' viewBox="0 0 {width} {total}" role="img" aria-label="{esc(title)}">'
        f"<title>{esc(title)}</title>" + "".join(parts) + "</svg>\n"
    )


__all__ = ["PALETTE", "bar_chart", "line_chart", "sparkline"]
