"""The tracked tree says why, not how it came to be: no issue numbers, no citations of the design document
outside the repository (the design is docs/architecture.md), no commit ids of this repository (git history
holds those), and module docstrings short enough to read (the long explanations live in docs/architecture.md)."""

from __future__ import annotations

import ast
import re
import shutil
import subprocess
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: Longest module docstring, in source lines (its opening and closing quotes included).
MAX_DOCSTRING_LINES = 25
#: The word issue then a number, with or without "#" or a space between (a folder name too): a reference to the
#: project's issue tracker.
ISSUE = re.compile(r"\bissues?\s*#?\s*\d+", re.IGNORECASE)
#: A section sign after SPEC: the original design document, which is not in the repository. Built from two
#: parts so that this file does not match itself.
SPEC_SECTION = re.compile("SPEC" + r"\s*" + "\N{SECTION SIGN}")
#: A word of 7 to 40 hex digits: a commit id when it is the prefix of one of this repository's commits.
HEX_WORD = re.compile(r"\b[0-9a-f]{7,40}\b")

pytestmark = pytest.mark.skipif(
    shutil.which("git") is None or not (ROOT / ".git").exists(), reason="needs a git checkout of the repository"
)


def _git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=True, timeout=60).stdout


@cache
def tracked_texts() -> dict[str, str]:
    """Every tracked file that exists and reads as UTF-8 text (binary files, such as the shipped models, are
    left out), by its path relative to the repository."""
    texts = {}
    for name in _git("ls-files", "-z").split("\0"):
        path = ROOT / name
        if not name or not path.is_file():
            continue
        data = path.read_bytes()
        if b"\0" in data:
            continue
        try:
            texts[name] = data.decode("utf-8")
        except UnicodeDecodeError:
            continue
    return texts


def matches(pattern: re.Pattern[str]) -> list[str]:
    """``file:line: match`` of every match of ``pattern`` in the tracked text files."""
    found = []
    for name, text in tracked_texts().items():
        for number, line in enumerate(text.splitlines(), 1):
            found += [f"{name}:{number}: {m.group()}" for m in pattern.finditer(line)]
    return found


def test_the_scan_sees_the_tree() -> None:
    texts = tracked_texts()
    assert {"README.md", "pyproject.toml", "gicore/error_policy.py"} <= texts.keys()


def test_no_issue_numbers() -> None:
    assert ISSUE.search("as Issue " + "#12 asks") and ISSUE.search("results/issue" + "22/web")  # the pattern bites
    found = matches(ISSUE)
    assert not found, "say why in the text itself; the issue tracker holds the history:\n" + "\n".join(found)


def test_no_citations_of_the_design_document_outside_the_repository() -> None:
    found = matches(SPEC_SECTION)
    assert not found, "cite docs/architecture.md by section name instead:\n" + "\n".join(found)


def test_no_commit_ids_of_this_repository() -> None:
    commits = _git("rev-list", "--all").split()
    assert commits
    by_prefix: dict[str, list[str]] = {}
    for commit in commits:
        by_prefix.setdefault(commit[:7], []).append(commit)

    def commit_ids(line: str) -> list[str]:
        return [w for w in HEX_WORD.findall(line) if any(c.startswith(w) for c in by_prefix.get(w[:7], ()))]

    assert commit_ids(f"fixed at {commits[0][:7]}, see {commits[-1]}.") == [commits[0][:7], commits[-1]]
    found = []
    for name, text in tracked_texts().items():
        for number, line in enumerate(text.splitlines(), 1):
            found += [f"{name}:{number}: {word}" for word in commit_ids(line)]
    assert not found, "git history holds the commits; say what the code does instead:\n" + "\n".join(found)


def test_module_docstrings_are_short() -> None:
    long = []
    for name, text in tracked_texts().items():
        if not name.endswith(".py"):
            continue
        body = ast.parse(text, name).body
        first = body[0] if body else None
        if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
            lines = (first.end_lineno or first.lineno) - first.lineno + 1
            if lines > MAX_DOCSTRING_LINES:
                long.append(f"{name}: {lines} lines")
    assert not long, (
        f"module docstrings over {MAX_DOCSTRING_LINES} lines: move the explanation into docs/architecture.md and "
        "point to it:\n" + "\n".join(long)
    )
