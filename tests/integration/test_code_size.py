"""Sizes that fit in a head (the developers' guide): no module of the packages over 600 lines, no function or
method over 80 lines, and bench's share of the packages' lines at most 25 %.

It covers every Python file of gicore, gigan_local, baseline_cloudbaking, network_sim, bench and web3d. The
module rule covers tests/ too; the function rule leaves tests/ out (a test reads as one scenario from setup to
assertion). The share counts the packages' shader sources too (their ``glsl/`` folders: GLSL that lived in
Python strings before it had files of its own). A function's length is ``end_lineno - lineno + 1`` as ast
reports it: from its ``def`` line to its last line, decorators excluded. Each test lists every offender at once.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("gicore", "gigan_local", "baseline_cloudbaking", "network_sim", "bench", "web3d")
MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 80
MAX_BENCH_SHARE = 0.25


def python_files(*folders: str) -> list[Path]:
    return sorted(p for folder in folders for p in (ROOT / folder).rglob("*.py") if "__pycache__" not in p.parts)


def shader_files(folder: str) -> list[Path]:
    return sorted(p for p in (ROOT / folder).rglob("*") if p.parent.name == "glsl" and p.is_file())


def line_count(path: Path) -> int:
    return len(path.read_text().splitlines())


def functions(path: Path) -> Iterator[tuple[str, int, int]]:
    """(qualified name, first line, length) of every function and method in ``path``, nested ones included."""

    def visit(node: ast.AST, prefix: str) -> Iterator[tuple[str, int, int]]:
        for child in ast.iter_child_nodes(node):
            name = prefix
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = f"{prefix}{child.name}."
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                yield name[:-1], child.lineno, child.end_lineno - child.lineno + 1
            yield from visit(child, name)

    yield from visit(ast.parse(path.read_text(), str(path)), "")


def test_no_module_over_600_lines() -> None:
    long = [
        f"{path.relative_to(ROOT)}: {n} lines"
        for path in python_files(*PACKAGES, "tests")
        if (n := line_count(path)) > MAX_MODULE_LINES
    ]
    assert not long, f"modules over {MAX_MODULE_LINES} lines:\n" + "\n".join(long)


def test_no_function_over_80_lines() -> None:
    long = [
        f"{path.relative_to(ROOT)}:{line} {name}: {n} lines"
        for path in python_files(*PACKAGES)
        for name, line, n in functions(path)
        if n > MAX_FUNCTION_LINES
    ]
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines:\n" + "\n".join(long)


def test_bench_is_at_most_a_quarter_of_the_packages() -> None:
    lines = {package: sum(map(line_count, python_files(package) + shader_files(package))) for package in PACKAGES}
    share = lines["bench"] / sum(lines.values())
    assert share <= MAX_BENCH_SHARE, f"bench/ is {share:.1%} of the lines, over {MAX_BENCH_SHARE:.0%}: {lines}"
