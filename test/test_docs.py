"""The user documentation (README.md, CHANGELOG.md, docs/*.md) stays finished and navigable.

A reader relies on what the documents show: no placeholder where output should be, no leftover
HTML comment, every relative link (and its ``#anchor``) leading somewhere, every repository path
named in code (``config/...``) existing, and a README short enough to be read (the reference
lives in docs/).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
DOCS = sorted([REPO / "README.md", REPO / "CHANGELOG.md", *(REPO / "docs").glob("*.md")])
README_MAX_LINES = 350

PLACEHOLDER = re.compile(r"DEMO_EXCERPT|\bTODO\b|\bTBD\b|\bFIXME\b|\bXXX\b")
LINK = re.compile(r"!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^(```|~~~)")
#: A repository path in a code span: a top-level folder of the repository, then a file name.
REPO_PATH = re.compile(r"`((?:config|docs|test|tools|pomdp_planner)/[A-Za-z0-9_./-]*[A-Za-z0-9_])`")


def rel(path: Path) -> str:
    return str(path.relative_to(REPO))


def prose_lines(text: str) -> list[tuple[int, str]]:
    """(line number, line) outside fenced code blocks: links in a code block are not links."""
    out, in_code = [], False
    for n, line in enumerate(text.splitlines(), 1):
        if FENCE.match(line.strip()):
            in_code = not in_code
            continue
        if not in_code:
            out.append((n, line))
    return out


def github_anchor(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, code marks and punctuation dropped, spaces to '-'."""
    text = heading.strip().lower().replace("`", "")
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for _, line in prose_lines(path.read_text(encoding="utf-8")):
        m = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if m:
            base = github_anchor(m.group(1))
            k = seen.get(base, 0)
            out.add(base if k == 0 else f"{base}-{k}")
            seen[base] = k + 1
    return out


def test_the_documents_exist():
    names = {rel(p) for p in DOCS}
    assert {"README.md", "CHANGELOG.md", "docs/cli.md", "docs/ros.md", "docs/models.md",
            "docs/benchmarks.md", "docs/THEORY.md", "docs/RESULTS.md", "docs/MODEL_SEARCH.md"} <= names


@pytest.mark.parametrize("path", DOCS, ids=rel)
def test_no_placeholder_or_html_comment(path):
    problems = []
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if m := PLACEHOLDER.search(line):
            problems.append(f"{rel(path)}:{n}: placeholder {m.group(0)!r}")
        if "<!--" in line or "-->" in line:
            problems.append(f"{rel(path)}:{n}: HTML comment")
    assert not problems, "\n".join(problems)


def prose_matches(path: Path, pattern: re.Pattern) -> list[tuple[int, str]]:
    """(line number, match) of ``pattern`` in the prose of ``path``."""
    return [(n, m) for n, line in prose_lines(path.read_text(encoding="utf-8")) for m in pattern.findall(line)]


@pytest.mark.parametrize("path", DOCS, ids=rel)
def test_relative_links_resolve(path):
    broken = []
    for n, target in prose_matches(path, LINK):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
            continue
        file_part, _, anchor = target.partition("#")
        dest = path if not file_part else (path.parent / file_part).resolve()
        if not dest.exists():
            broken.append(f"{rel(path)}:{n}: {target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            broken.append(f"{rel(path)}:{n}: {target}: no heading with anchor #{anchor} in {rel(dest)}")
    assert not broken, "\n".join(broken)


@pytest.mark.parametrize("path", DOCS, ids=rel)
def test_repository_paths_named_exist(path):
    missing = [f"{rel(path)}:{n}: `{name}` does not exist" for n, name in prose_matches(path, REPO_PATH)
               if not (REPO / name).exists()]
    assert not missing, "\n".join(missing)


def test_readme_is_short():
    lines = (REPO / "README.md").read_text(encoding="utf-8").count("\n")
    assert lines <= README_MAX_LINES, (
        f"README.md has {lines} lines (at most {README_MAX_LINES}): put reference material into docs/ "
        "(cli.md, ros.md, models.md, benchmarks.md) and link to it")


def test_readme_has_no_development_history():
    text = (REPO / "README.md").read_text(encoding="utf-8")
    assert not re.search(r"(?i)\bissue \d+|before the fix", text)


def test_anchor_rule():
    """The anchor rule the link check uses, on headings of these documents."""
    assert github_anchor("Topics and message layouts (std_msgs / diagnostic_msgs only)") == \
        "topics-and-message-layouts-std_msgs--diagnostic_msgs-only"
    assert github_anchor("Memory and CPU (soak)") == "memory-and-cpu-soak"
    assert github_anchor("Cassandra `.POMDP` files") == "cassandra-pomdp-files"
    assert github_anchor("Every experiment of the paper: `bench all`") == "every-experiment-of-the-paper-bench-all"
