"""The GPU run's scripts: scripts/gpu_wheels.sh splits and batches wheels to fit one copy to the GPU machine each, and
scripts/gpu_table1.sh reassembles them, checks their hashes, skips what is installed and says what it would run
(--dry-run), or lists what has not arrived yet (--stage-only); scripts/gpu_slim_wheel.py slims mitsuba's and
pyoidn's wheels to what the project loads."""

from __future__ import annotations

import base64
import csv
import hashlib
import importlib.util
import io
import os
import shutil
import struct
import subprocess
import sys
import zipfile
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
    """The repository's tree as a run copies it to the GPU machine (what gpu_wheels.sh subtracts from a run's bytes)."""
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
    # SLIM=0: these wheels are random bytes, not zip files
    env = {"CARRY_MIB": str(CARRY_MIB), "MARGIN_MIB": "0", "PART_MIB": str(PART_MIB), "SLIM": "0"}
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


def _slim_module():
    """scripts/gpu_slim_wheel.py, imported (scripts/ is no package)."""
    spec = importlib.util.spec_from_file_location("gpu_slim_wheel", ROOT / "scripts" / "gpu_slim_wheel.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def _fake_elf(needed: list[str]) -> bytes:
    """A 64-bit ELF file whose sections are a string table and a dynamic section that NEEDs ``needed``."""
    strtab, entries = b"\0", b""
    for name in needed:
        entries += struct.pack("<qQ", 1, len(strtab))  # DT_NEEDED: the name's offset in the string table
        strtab += name.encode() + b"\0"
    dynamic = entries + struct.pack("<qQ", 0, 0)
    strtab_at, dynamic_at = 64, 64 + len(strtab)
    sections_at = dynamic_at + len(dynamic)
    ident = b"\x7fELF\x02\x01\x01" + bytes(9)
    header = ident + struct.pack("<HHIQQQIHHHHHH", 3, 62, 1, 0, 0, sections_at, 0, 64, 0, 0, 64, 3, 0)
    section = struct.Struct("<IIQQQQIIQQ")  # name, type, flags, addr, offset, size, link, info, align, entsize
    sections = bytes(64) + section.pack(0, 3, 0, 0, strtab_at, len(strtab), 0, 0, 1, 0)
    sections += section.pack(0, 6, 0, 0, dynamic_at, len(dynamic), 1, 0, 8, 16)
    return header + strtab + dynamic + sections


def _write_wheel(path: Path, files: dict[str, bytes]) -> Path:
    dist_info = "-".join(path.name.split("-")[:2]) + ".dist-info"
    files = files | {f"{dist_info}/METADATA": b"Metadata-Version: 2.1\n", f"{dist_info}/RECORD": b"stale,,\n"}
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as wheel:
        for name, data in files.items():
            wheel.writestr(name, data)
    return path


def _names_and_true_record(path: Path) -> set[str]:
    """The wheel's file names, once its RECORD is checked: every file listed once, with its sha256 and size."""
    with zipfile.ZipFile(path) as wheel:
        record = "-".join(path.name.split("-")[:2]) + ".dist-info/RECORD"
        rows = list(csv.reader(io.StringIO(wheel.read(record).decode())))
        assert sorted(r[0] for r in rows) == sorted(wheel.namelist())
        for name, digest, size in rows:
            if name != record:
                data = wheel.read(name)
                sha = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
                assert (digest, size) == (f"sha256={sha}", str(len(data))), name
        return set(wheel.namelist())


OIDN = "pyoidn/oidn/lib/"
CORE = "libOpenImageDenoise_core.so.2.5.1"


def _fake_pyoidn(folder: Path) -> Path:
    """pyoidn's layout: each library under several names, devices the core dlopens, tools, cmake files."""
    files = {"pyoidn/__init__.py": b"", "pyoidn/capi.py": b"# dlopens oidn/lib/libOpenImageDenoise.so\n"}
    files |= {f"pyoidn/oidn/bin/{t}": _fake_elf([CORE]) for t in ("oidnDenoise", "oidnTest")}
    files |= {f"{OIDN}libOpenImageDenoise.so{v}": _fake_elf([CORE, "libc.so.6"]) for v in ("", ".2", ".2.5.1")}
    files |= {f"{OIDN}{CORE}": _fake_elf(["libc.so.6"]), f"{OIDN}libur_loader.so.0": _fake_elf([])}
    needs = {"cpu": [CORE, "libtbb.so.12"], "cuda": [CORE, "libcuda.so.1"], "hip": [CORE], "sycl": ["libsycl.so.9"]}
    files |= {f"{OIDN}libOpenImageDenoise_device_{d}.so.2.5.1": _fake_elf(n) for d, n in needs.items()}
    files |= {f"{OIDN}libsycl.so.9": _fake_elf(["libur_loader.so.0"])}
    files |= {f"{OIDN}libtbb.so{v}": _fake_elf([]) for v in ("", ".12", ".12.19")}
    files |= {f"{OIDN}libtbbbind_2_5.so{v}": _fake_elf(["libhwloc.so.15"]) for v in (".3", ".3.19")}
    files[f"{OIDN}cmake/OpenImageDenoise-2.5.1/OpenImageDenoiseConfig.cmake"] = b""
    return _write_wheel(folder / "pyoidn-2.5.1.0-py3-none-manylinux2014_x86_64.whl", files)


def _fake_mitsuba(folder: Path, plugins: list[str], plugin_needs: dict[str, list[str]] | None = None) -> Path:
    """mitsuba's layout: 13 variants' modules, libraries, plugins, data, headers and cmake files."""
    files = {"mitsuba/__init__.py": b"", "mitsuba/python/ad/__init__.py": b"", "mitsuba/data/ior/Au.eta.spd": b"1"}
    files |= {f"mitsuba/{f}": b"x" for f in ("data/srgb.coeff", "data/sunsky/sunsky_datasets.bin", "cmake/m.cmake")}
    files |= {"mitsuba/include/mitsuba/mitsuba.h": b"", "mitsuba/libembree3.so": _fake_elf([])}
    files |= {"mitsuba/libmitsuba.so": _fake_elf(["libembree3.so"])}
    variants = [f"{m}_{c}" for m in ("scalar", "llvm_ad", "cuda_ad") for c in ("rgb", "spectral", "mono_polarized")]
    files |= {f"mitsuba/{v}.cpython-312-x86_64-linux-gnu.so": _fake_elf(["libmitsuba.so"]) for v in variants}
    needs = plugin_needs or {}
    files |= {f"mitsuba/plugins/{p}.so": _fake_elf(["libmitsuba.so", *needs.get(p, [])]) for p in plugins}
    return _write_wheel(folder / "mitsuba-3.9.1-cp312-cp312-manylinux_2_28_x86_64.whl", files)


@pytest.mark.parametrize("compression", ["lzma", "deflate"])
def test_slimming_keeps_what_the_project_loads_with_a_true_record(tmp_path: Path, compression: str):
    slim = _slim_module()
    pyoidn = _fake_pyoidn(tmp_path)
    done = slim.rewrite_wheel(pyoidn, compression)
    assert done.slimmed and done.after < done.before and (done.files, done.files_before) == (10, 22)
    # each library once, under the name Python, the core or a kept library asks for: no HIP, SYCL, tools, cmake
    libs = ["libOpenImageDenoise.so", CORE, "libOpenImageDenoise_device_cpu.so.2.5.1", "libtbb.so.12"]
    libs += ["libOpenImageDenoise_device_cuda.so.2.5.1", "libtbbbind_2_5.so.3"]
    dist_info = "pyoidn-2.5.1.0.dist-info"
    expected = {"pyoidn/__init__.py", "pyoidn/capi.py", f"{dist_info}/METADATA", f"{dist_info}/RECORD"}
    assert _names_and_true_record(pyoidn) == expected | {OIDN + lib for lib in libs}
    with zipfile.ZipFile(pyoidn) as wheel:
        assert {i.compress_type for i in wheel.infolist()} == {slim.COMPRESSION[compression]}

    plugins = slim.MITSUBA_PLUGINS + ["sphere", "volpath", "sunsky"]
    mitsuba = _fake_mitsuba(tmp_path, plugins)
    assert slim.rewrite_wheel(mitsuba, compression).slimmed
    names = _names_and_true_record(mitsuba)
    kept_variants = {n.split("/")[1].split(".")[0] for n in names if ".cpython-" in n}
    assert kept_variants == {"scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb"}
    assert {f"mitsuba/plugins/{p}.so" for p in slim.MITSUBA_PLUGINS + ["sphere"]} <= names
    assert {"mitsuba/libmitsuba.so", "mitsuba/libembree3.so", "mitsuba/data/ior/Au.eta.spd"} <= names
    dropped = ["plugins/volpath.so", "plugins/sunsky.so", "data/srgb.coeff", "data/sunsky/sunsky_datasets.bin"]
    assert not {f"mitsuba/{d}" for d in dropped + ["include/mitsuba/mitsuba.h", "cmake/m.cmake"]} & names


def test_other_wheels_keep_their_files_and_record(tmp_path: Path):
    slim = _slim_module()
    other = _write_wheel(tmp_path / "zz_other-1.0-py3-none-any.whl", {"zz_other/__init__.py": b"x = 1\n" * 100})
    with zipfile.ZipFile(other) as wheel:
        before = {n: wheel.read(n) for n in wheel.namelist()}
    assert slim.rewrite_wheel(other, "deflate") is None  # nothing to gain
    done = slim.rewrite_wheel(other, "lzma")
    assert not done.slimmed
    with zipfile.ZipFile(other) as wheel:
        assert {n: wheel.read(n) for n in wheel.namelist()} == before
        assert {i.compress_type for i in wheel.infolist()} == {zipfile.ZIP_LZMA}


def test_slimming_refuses_to_drop_what_is_required_or_needed(tmp_path: Path):
    slim = _slim_module()
    no_film = _fake_mitsuba(tmp_path, [p for p in slim.MITSUBA_PLUGINS if p != "hdrfilm"])
    with pytest.raises(SystemExit, match=r"lack mitsuba/plugins/hdrfilm\.so:"):
        slim.rewrite_wheel(no_film)
    # a kept plugin that links a dropped one
    linked = _fake_mitsuba(tmp_path, [*slim.MITSUBA_PLUGINS, "sunsky"], {"bitmap": ["sunsky.so"]})
    with pytest.raises(SystemExit, match=r"sunsky\.so \(NEEDED by mitsuba/plugins/bitmap\.so\)"):
        slim.rewrite_wheel(linked)


def test_gpu_wheels_slims_by_default_and_batches_the_slim_wheels(tmp_path: Path):
    src, out = tmp_path / "src", tmp_path / "out"
    src.mkdir()
    _fake_pyoidn(src)
    _write_wheel(src / "zz_other-1.0-py3-none-any.whl", {"zz_other/__init__.py": b""})
    env = {"CARRY_MIB": str(CARRY_MIB), "MARGIN_MIB": "0"}
    proc = _bash("gpu_wheels.sh", "--from", str(src), str(out), env=env)
    assert proc.returncode == 0, proc.stderr
    assert "slim pyoidn-2.5.1.0-py3-none-manylinux2014_x86_64.whl: " in proc.stdout
    assert "(10 of 22 files, lzma)" in proc.stdout
    assert "the 1 other wheels, same files, lzma: " in proc.stdout and "all wheels: " in proc.stdout
    [batch] = out.glob("batch*")
    sums = dict(line.split()[::-1] for line in (batch / "SHA256SUMS").read_text().splitlines())
    assert sums == {w.name: hashlib.sha256(w.read_bytes()).hexdigest() for w in batch.glob("*.whl")}
    assert len(sums) == 2 and f"{OIDN}libtbb.so.12" in _names_and_true_record(batch / next(iter(sums)))
