"""The GPU run's scripts: scripts/gpu_wheels.sh splits and batches wheels to fit one device run each, and
scripts/gpu_table1.sh reassembles them, checks their hashes, skips what is installed and says what it would run
(--dry-run), or lists what has not arrived yet (--stage-only)."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers.guards import HANG_GUARD_S

ROOT = Path(__file__).resolve().parents[2]
MIB = 1024 * 1024
#: Fake wheels: file name -> size in bytes; mitsuba's is split into parts; numpy is installed here at a newer
#: version, zz-not-installed is not installed.
WHEELS = {
    "mitsuba-9.9.9-cp312-cp312-manylinux_2_28_x86_64.whl": 5 * MIB + 123,
    "drjit-9.9.9-cp312-cp312-manylinux_2_28_x86_64.whl": MIB,
    "numpy-1.0.0-py3-none-any.whl": 50_000,
    "zz_not_installed-1.0-py3-none-any.whl": 40_000,
}
PART_MIB, BATCH_MIB = 2, 4

pytestmark = pytest.mark.skipif(shutil.which("split") is None, reason="needs coreutils (split, sha256sum)")


def _tree_bytes() -> int:
    """The repository's tree as the device tool sends it (what gpu_wheels.sh subtracts from a run's bytes)."""
    files = subprocess.run(
        ["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=ROOT, capture_output=True, check=True
    ).stdout.split(b"\0")
    return sum((ROOT / f.decode()).stat().st_size for f in files if f and (ROOT / f.decode()).is_file())


#: A run's MiB in the test: the tree (rounded up) and room for a batch of at most BATCH_MIB.
CARRY_MIB = -(-_tree_bytes() // MIB) + BATCH_MIB


def _bash(script: str, *args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    env = os.environ | {"PYTHON": sys.executable} | (env or {})
    return subprocess.run(
        ["bash", f"scripts/{script}", *args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=HANG_GUARD_S
    )


@pytest.fixture(scope="module")
def batches(tmp_path_factory) -> Path:
    """gpu_wheels.sh --from a folder of fake wheels, with batches of BATCH_MIB (the device's limit made small);
    only the batches are kept, as a device receives them."""
    src, out = tmp_path_factory.mktemp("src"), tmp_path_factory.mktemp("wheels") / "w"
    for i, (name, size) in enumerate(WHEELS.items()):
        (src / name).write_bytes(os.urandom(size) if i == 0 else bytes([i]) * size)
    env = {"CARRY_MIB": str(CARRY_MIB), "MARGIN_MIB": "0", "PART_MIB": str(PART_MIB)}
    proc = _bash("gpu_wheels.sh", "--from", str(src), str(out), env=env)
    assert proc.returncode == 0, proc.stderr
    assert f"{len(WHEELS)} wheels in " in proc.stdout
    sums = dict(line.split()[::-1] for line in (out / "SHA256SUMS").read_text().splitlines())
    assert sums == {name: hashlib.sha256((src / name).read_bytes()).hexdigest() for name in WHEELS}
    shutil.rmtree(out / "wheels")
    return out


def test_wheels_are_split_and_batched_to_fit_one_run_each(batches: Path):
    found = sorted(batches.glob("batch*"))
    assert len(found) >= 2
    for batch in found:
        assert (batch / "SHA256SUMS").read_text() == (batches / "SHA256SUMS").read_text()
        assert (
            sum(f.stat().st_size for f in batch.iterdir() if f.name != "SHA256SUMS") <= CARRY_MIB * MIB - _tree_bytes()
        )
    big = next(iter(WHEELS))
    parts = sorted(batches.glob(f"batch*/{big}.part.*"), key=lambda p: p.name)
    assert len(parts) == 3 and all(p.stat().st_size <= PART_MIB * MIB for p in parts)
    assert not list(batches.glob(f"batch*/{big}"))
    whole = b"".join(p.read_bytes() for p in parts)
    assert hashlib.sha256(whole).hexdigest() in (batches / "SHA256SUMS").read_text()


def test_dry_run_reassembles_skips_what_is_installed_and_prints_the_runs(batches: Path, tmp_path: Path):
    no_reference = {"VARIANT_REFERENCE": str(tmp_path / "none")}
    proc = _bash(
        "gpu_table1.sh", "--dry-run", "--wheels", str(batches), "--out", str(tmp_path / "out"), env=no_reference
    )
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert f"wheel {next(iter(WHEELS))} ready (from 3 parts)" in out and "drjit-9.9.9" in out
    assert "have numpy 2." in out and "install zz-not-installed 1.0 (have: none)" in out
    install = next(line for line in out.splitlines() if "pip install --quiet --no-index --no-deps --find-links" in line)
    assert "zz_not_installed-1.0" in install and "numpy-1.0.0" not in install
    assert "would run: " in out and "pip install --quiet --no-index --no-deps --no-build-isolation -e ." in out
    assert "bench latency --quick --resolution 256 --model " in out
    # no model trained at 512²: the shipped one resized, then measured at that side
    assert "gigan_local.resize_cli " in out and "--resolution 512 --out /tmp/gigan_gpu_results/model_512" in out
    assert "bench latency --quick --resolution 512 --model /tmp/gigan_gpu_results/model_512/model_fp16.onnx" in out
    # the bake on CUDA against the CPU's after the latency runs; the CPU maps from VARIANT_REFERENCE where carried
    assert out.index("bench variants --quick --out ") > out.index("bench latency --quick")
    env = {"VARIANT_REFERENCE": str(tmp_path)}
    again = _bash("gpu_table1.sh", "--dry-run", "--wheels", str(batches), "--out", str(tmp_path / "out"), env=env)
    assert f"bench variants --quick --variants cuda --reference {tmp_path} --out " in again.stdout
    assert "bench render --quick --renderers gl --gl-resolutions 256,512" in out and "bench report" in out
    assert not (tmp_path / "out").exists()  # a dry run writes nothing


def test_a_wheel_whose_parts_have_not_all_arrived_is_named(batches: Path, tmp_path: Path):
    partial = shutil.copytree(batches, tmp_path / "partial")
    big = next(iter(WHEELS))
    next(partial.glob(f"batch*/{big}.part.ab")).unlink()
    staged = _bash("gpu_table1.sh", "--stage-only", "--wheels", str(partial), env={"STAGE": str(tmp_path / "st")})
    assert staged.returncode == 0 and f"incomplete: {big} (2 parts here)" in staged.stdout
    assert "drjit" in staged.stdout and "ready" in staged.stdout
    run = _bash(
        "gpu_table1.sh", "--wheels", str(partial), "--out", str(tmp_path / "o"), env={"STAGE": str(tmp_path / "st")}
    )
    assert run.returncode == 3
    [error] = [line for line in run.stderr.splitlines() if line.startswith("error:")]
    assert error.startswith(f"error: 1 wheels are incomplete ({big} (2 parts here), ...): carry the batches")


def test_a_corrupt_part_fails_its_hash(batches: Path, tmp_path: Path):
    corrupt = shutil.copytree(batches, tmp_path / "corrupt")
    part = next(corrupt.glob(f"batch*/{next(iter(WHEELS))}.part.aa"))
    data = bytearray(part.read_bytes())
    data[0] ^= 0xFF
    part.write_bytes(bytes(data))
    proc = _bash("gpu_table1.sh", "--stage-only", "--wheels", str(corrupt), env={"STAGE": str(tmp_path / "st")})
    assert proc.returncode == 0 and f"incomplete: {next(iter(WHEELS))} (3 parts here)" in proc.stdout
