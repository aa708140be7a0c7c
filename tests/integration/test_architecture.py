"""The architecture (docs/architecture.md, Import contracts), checked: the import-linter contracts in
pyproject.toml (layers bench -> the two systems and the network simulator -> gicore, the systems independent
of each other, no cycle among a package's modules, benches import no bench, Mitsuba only behind gicore.render),
every registered bench under the benches' contract, and no import inside a function between bench modules
(such imports hide cycles from the reader).
"""

from __future__ import annotations

import ast
import subprocess
import sys
import tomllib
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[2]


def test_import_contracts_hold() -> None:
    lint = Path(sys.executable).parent / "lint-imports"
    proc = subprocess.run([str(lint), "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "broken" not in proc.stdout.lower().replace("0 broken", ""), proc.stdout


def test_bench_modules_import_each_other_only_at_top_level() -> None:
    late = []
    for path in sorted((ROOT / "bench").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for inner in ast.walk(node):
                    if isinstance(inner, ast.ImportFrom) and (inner.module or "").split(".")[0] == "bench":
                        late.append(f"{path.name}:{inner.lineno} from {inner.module}")
                    if isinstance(inner, ast.Import) and any(a.name.split(".")[0] == "bench" for a in inner.names):
                        late.append(f"{path.name}:{inner.lineno} import")
    assert not late, late


def test_every_registered_bench_is_under_the_benches_contract() -> None:
    from bench import registry

    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    [protected] = [c for c in contracts if c["type"] == "protected"]
    modules = {m.__name__ for m in vars(registry).values() if isinstance(m, ModuleType)}
    benches = {name for name in modules if name.startswith("bench.")}  # network_sim.selftest_report is no bench
    assert benches <= set(protected["protected_modules"]), benches - set(protected["protected_modules"])
