"""The Web3D page's JavaScript checker (``npm run check`` in web3d/static/): TypeScript checks every module against
its JSDoc types (strict, the page's modules with the window's globals, map_worker.js with a worker's), then
tools/rules.mjs holds them to the code-size rules (600 lines a module, 80 a function) and refuses any HTML written
into the document. The checker passes on the page and fails on a small bad file of each kind.

Without web3d/static/node_modules/typescript (``make setup`` runs npm ci there) the tests skip and say so, except
under ``CI=true``, where they fail.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from web3d.site import WEB_DIR

TSC = WEB_DIR / "node_modules" / "typescript" / "bin" / "tsc"
RULES = WEB_DIR / "tools" / "rules.mjs"
#: Seconds the checker may take on 2 busy cores (a hang guard; it takes about 10 s).
CHECK_TIMEOUT_S = 300


@pytest.fixture(scope="module")
def node() -> str:
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None or not TSC.is_file():
        reason = f"{TSC} is missing: run `make setup` (npm ci in web3d/static/, which needs Node 20 and npm)"
        if os.environ.get("CI") == "true":
            pytest.fail(reason)
        pytest.skip(reason)
    return node


def run(argv: list[str], cwd: Path = WEB_DIR) -> subprocess.CompletedProcess[str]:
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=CHECK_TIMEOUT_S, check=False)


def test_the_page_passes_its_checker(node: str) -> None:
    done = run(["npm", "run", "--silent", "check"])
    assert done.returncode == 0, done.stdout + done.stderr


def test_the_type_check_fails_on_a_type_error_and_on_an_untyped_parameter(node: str, tmp_path: Path) -> None:
    """A file beside the page's modules, checked with the page's settings: a module's export called with the wrong
    type, and a function whose parameter has no type."""
    (tmp_path / "bad.js").write_text(
        f'import {{ median }} from "{WEB_DIR}/js/glutil.js";\n'
        'export const middle = median("3");\n'
        "export function untyped(x) {\n  return x;\n}\n"
    )
    config = {"extends": str(WEB_DIR / "tsconfig.json"), "include": ["bad.js"], "exclude": []}
    (tmp_path / "tsconfig.json").write_text(json.dumps(config))
    done = run([node, str(TSC), "-p", str(tmp_path / "tsconfig.json")], cwd=tmp_path)
    assert done.returncode != 0
    assert "bad.js(2," in done.stdout and "error TS2345" in done.stdout, done.stdout  # not assignable to number[]
    assert "bad.js(3," in done.stdout and "error TS7006" in done.stdout, done.stdout  # implicitly 'any'


def test_the_rules_refuse_html_writes_and_long_functions_and_modules(node: str, tmp_path: Path) -> None:
    body = "".join(f"  el.title = '{i}';\n" for i in range(79))
    (tmp_path / "bad.js").write_text(
        'const el = document.body;\nel.innerHTML = "<b>x</b>";\nel.insertAdjacentHTML("beforeend", "<i>y</i>");\n'
        f'document.write("z");\nexport function long() {{\n{body}}}\nexport function short() {{\n  return 1;\n}}\n'
    )
    (tmp_path / "long.js").write_text("export const x = 1;\n" * 601)
    done = run([node, str(RULES), str(tmp_path / "bad.js"), str(tmp_path / "long.js")])
    assert done.returncode == 1
    offences = done.stdout.replace(f"{tmp_path}/", "").splitlines()
    expected = [
        "bad.js:2 innerHTML writes HTML",
        "bad.js:3 insertAdjacentHTML writes HTML",
        "bad.js:4 write writes HTML",
        "bad.js:5 long: 81 lines, over 80",
        "long.js:1 module: 601 lines, over 600",
    ]
    assert len(offences) == len(expected) and all(map(str.startswith, offences, expected)), done.stdout
