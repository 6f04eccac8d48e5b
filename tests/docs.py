"""Reading the project's markdown pages for the tests that keep them true: the pages,
their fenced blocks, their links and their headings' ids."""

from __future__ import annotations

import re
import unicodedata
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

_FENCE = re.compile(r"^(```+|~~~+)\s*([^\s`]*)(.*)$")
_LINK = re.compile(r"(?<!!)\[(?:[^\]\[]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_IMAGE = re.compile(r"!\[[^\]]*\]\(\s*<?([^)\s>]+)>?\s*\)")
_CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1")


def doc_pages() -> list[Path]:
    """README.md and every page under docs/, in a stable order."""
    return [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]


@dataclass(frozen=True)
class Block:
    """One fenced block of a page: its info string's language, the words after it,
    its text, and the line of its opening fence (1-based)."""

    lang: str
    info: str
    text: str
    line: int


def blocks(text: str) -> list[Block]:
    """The fenced blocks of a markdown text, in order."""
    out: list[Block] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        m = _FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        fence, lang, rest = m.group(1), m.group(2), m.group(3).strip()
        body: list[str] = []
        j = i + 1
        while j < len(lines) and not lines[j].startswith(fence):
            body.append(lines[j])
            j += 1
        out.append(Block(lang, rest, "\n".join(body) + "\n", i + 1))
        i = j + 1
    return out


def _prose_lines(text: str) -> list[tuple[int, str]]:
    """(line number, line) of the lines outside fenced blocks."""
    out, fence = [], ""
    for n, line in enumerate(text.splitlines(), 1):
        m = _FENCE.match(line)
        if fence:
            if line.startswith(fence):
                fence = ""
            continue
        if m:
            fence = m.group(1)
            continue
        out.append((n, line))
    return out


def links(text: str) -> list[tuple[str, int]]:
    """The targets of the inline links and images of a markdown text, with their line,
    leaving out fenced blocks and code spans (where brackets are code)."""
    found: list[tuple[str, int]] = []
    for n, line in _prose_lines(text):
        line = _CODE_SPAN.sub("", line)
        hits = [(m.start(), m.group(1)) for m in _LINK.finditer(line)]
        hits += [(m.start(), m.group(1)) for m in _IMAGE.finditer(line)]
        found += [(target, n) for _, target in sorted(hits)]
    return found


def _slug(heading: str) -> str:
    """GitHub's id for a heading's text: markup and punctuation dropped, lower case,
    spaces to hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link keeps its text
    text = text.strip().lower()
    kept = []
    for ch in text:
        if ch in " -_" or unicodedata.category(ch)[0] in "LN":
            kept.append(ch)
    return "".join(kept).replace(" ", "-")


def heading_ids(text: str) -> set[str]:
    """The anchors a markdown page's headings get (a repeated one gets -1, -2, ...)."""
    seen: dict[str, int] = {}
    ids: set[str] = set()
    for _, line in _prose_lines(text):
        m = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if not m:
            continue
        slug = _slug(m.group(1))
        if slug in seen:
            seen[slug] += 1
            ids.add(f"{slug}-{seen[slug]}")
        else:
            seen[slug] = 0
            ids.add(slug)
    return ids
