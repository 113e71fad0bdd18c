"""Every pointer into docs/ resolves: the file exists and the anchor names one of its headings.

Checked: ``docs/<file>.md`` and ``docs/<file>.md#<anchor>`` written anywhere in src/, tests/,
benchmarks/, configs/, README.md and docs/*.md, and the relative markdown links of README.md and
docs/*.md (files, images and ``#anchor``s). The design lives in docs/design.md: no pointer to the
old out-of-tree design document may remain. Anchors follow GitHub's rules (:func:`anchor`).
"""

from __future__ import annotations

import re
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCANNED = ("src", "tests", "benchmarks", "configs")
SUFFIXES = {".py", ".md", ".toml", ".txt", ".cfg", ".yaml", ".yml", ".sh"}
# Written split so that this file does not match itself.
FORBIDDEN = ("DESIGN" + " §", "DESIGN" + ".md")

DOC_POINTER = re.compile(r"(?<![\w/.-])docs/([\w.-]+\.md)(?:#([\w-]+))?")
MARKDOWN_LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
HEADING = re.compile(r"^ {0,3}(#{1,6})[ \t]+(.*?)[ \t]*#*[ \t]*$")
FENCE = re.compile(r"^ {0,3}(`{3,}|~{3,})")
# A cited test or benchmark file (e.g. ``tests/test_physics_stability.py``) must exist.
CITED_FILE = re.compile(r"(?<![\w/.-])((?:tests|benchmarks)/[\w/]+\.py)")
HTML_ANCHOR = re.compile(r"<a\s+(?:name|id)=\"([^\"]+)\"")


def anchor(heading: str) -> str:
    """GitHub's anchor of a heading: link text kept, lower case, punctuation dropped, ' ' → '-'."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # [text](url) → text
    text = text.strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)  # \w: unicode letters, digits and "_" stay
    return text.replace(" ", "-")


@cache
def anchors(path: Path) -> frozenset[str]:
    """Anchors of the headings (outside fenced code) of a markdown file, duplicates numbered."""
    seen: dict[str, int] = {}
    found = set()
    fence = None
    for line in path.read_text(encoding="utf-8").splitlines():
        opening = FENCE.match(line)
        if opening:
            marker = opening.group(1)
            if fence is None:
                fence = marker
            elif marker[0] == fence[0] and len(marker) >= len(fence):
                fence = None
            continue
        if fence is not None:
            continue
        found.update(HTML_ANCHOR.findall(line))
        match = HEADING.match(line)
        if match:
            base = anchor(match.group(2))
            count = seen.get(base, 0)
            seen[base] = count + 1
            found.add(base if count == 0 else f"{base}-{count}")
    return frozenset(found)


def scanned_files() -> list[Path]:
    files = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    for name in SCANNED:
        for path in sorted((ROOT / name).rglob("*")):
            skip = "__pycache__" in path.parts or any(p.endswith(".egg-info") for p in path.parts)
            if skip or not path.is_file() or path.suffix not in SUFFIXES:
                continue
            files.append(path)
    return [f for f in files if f.is_file()]


def problems_in(path: Path) -> list[str]:
    """One line per dangling pointer or link (``file:line: what``)."""
    text = path.read_text(encoding="utf-8")
    relative = path.relative_to(ROOT)
    markdown = path.suffix == ".md" and (path.parent == ROOT or path.parent == ROOT / "docs")
    out = []
    for number, line in enumerate(text.splitlines(), 1):
        where = f"{relative}:{number}"
        for word in FORBIDDEN:
            if word in line:
                out.append(f"{where}: {word!r} (point to docs/design.md#<heading> instead)")
        for match in DOC_POINTER.finditer(line):
            out += check_target(ROOT / "docs" / match.group(1), match.group(2), where)
        for match in CITED_FILE.finditer(line):
            if not (ROOT / match.group(1)).is_file():
                out.append(f"{where}: cites {match.group(1)}, which does not exist")
        if markdown:
            for match in MARKDOWN_LINK.finditer(line):
                out += check_link(path, match.group(1), where)
    return out


def check_link(source: Path, target: str, where: str) -> list[str]:
    if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.IGNORECASE):  # http:, https:, mailto:, ...
        return []
    file_part, _, fragment = target.partition("#")
    destination = (source.parent / file_part).resolve() if file_part else source
    return check_target(destination, fragment or None, where)


def check_target(path: Path, fragment: str | None, where: str) -> list[str]:
    shown = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
    if not path.exists():
        return [f"{where}: {shown} does not exist"]
    if fragment is None:
        return []
    if path.suffix != ".md":
        return [f"{where}: #{fragment} on {shown}, which is not a markdown file"]
    if fragment not in anchors(path):
        return [f"{where}: {shown} has no heading with anchor #{fragment}"]
    return []


@pytest.mark.parametrize(
    ("heading", "expected"),
    [
        ("Physical model", "physical-model"),
        (
            "trajectory.npz (written by `reconphys simulate`)",
            "trajectorynpz-written-by-reconphys-simulate",
        ),
        (
            "One substep (semi-implicit Euler, step h = frame_dt / substeps)",
            "one-substep-semi-implicit-euler-step-h--frame_dt--substeps",
        ),
        ("Speed: frames per second for 2,048 anchors", "speed-frames-per-second-for-2048-anchors"),
        ("Five times the data (2026-11-24)", "five-times-the-data-2026-11-24"),
        ("Links [in](x.md) headings", "links-in-headings"),
    ],
)
def test_anchor_follows_github_rules(heading, expected):
    assert anchor(heading) == expected


def test_design_page_has_one_heading_per_section():
    expected = {
        "what-it-is",
        "data-flow",
        "conventions",
        "physical-model",
        "attribute-ranges",
        "asset-format",
        "synthetic-dataset",
        "models",
        "evaluation",
        "compute",
        "package-layers",
    }
    assert expected <= anchors(ROOT / "docs" / "design.md")


def test_every_docs_pointer_resolves():
    problems = [line for path in scanned_files() for line in problems_in(path)]
    assert not problems, "dangling doc pointers:\n" + "\n".join(problems)
