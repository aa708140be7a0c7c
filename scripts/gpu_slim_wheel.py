"""Rewrite the wheels that scripts/gpu_wheels.sh carries to a GPU machine without network into fewer bytes: a
run there copies at most 64 MiB, and mitsuba's and pyoidn's wheels (150 MB) are mostly variants, plugins and
devices the project never loads.

    python scripts/gpu_slim_wheel.py [--compression lzma|deflate] WHEEL...

Each wheel is rewritten in place under its name and tags. mitsuba's and pyoidn's are slimmed, with a new RECORD
(sha256 and size of each file), and a line each gives its size before and after; the others keep their files
and RECORD, recompressed (lzma only), and one line sums them.

- mitsuba: the variants of gicore.mitsuba_variant (scalar_rgb, llvm_ad_rgb, cuda_ad_rgb; mitsuba.variants(),
  compiled in, still names all 13, and set_variant fails on the others), every top-level library, the plugins
  the project's scenes load, those Mitsuba's own libraries load by name (the default sampler, film, filter,
  textures, merge of load_dict's optimiser, ...) and a few more of the common kinds; no headers, cmake or
  pkgconfig files, no srgb.coeff (the spectral variants' RGB upsampling model) and no sunsky data.
- pyoidn: the Python code and, of oidn/lib, the library Python dlopens (libOpenImageDenoise.so), the CPU and CUDA
  device modules the core dlopens, TBB's tbbbind modules, and what those NEED, each once under the name the
  loader asks for (the wheel stores each library under three names); no HIP or SYCL devices, level-zero or
  ur_loader libraries, bin/ tools or cmake files.

A slim wheel that lacks a file the rules require, or a library a kept one NEEDs (DT_NEEDED) and the wheel had,
is an error: a new release that renames files stops here rather than on the GPU machine. lzma (the default)
packs the libraries into about 2/3 of deflate's bytes, which fits the wheels into two runs; pip then needs
Python's lzma module (`python3 -c 'import lzma'` on the GPU machine). deflate is what every wheel tool reads.
"""

from __future__ import annotations

import argparse
import base64
import fnmatch
import hashlib
import os
import re
import struct
import sys
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

MIB = 1024 * 1024
COMPRESSION = {"lzma": zipfile.ZIP_LZMA, "deflate": zipfile.ZIP_DEFLATED}

#: gicore.mitsuba_variant's variants: CUDA_VARIANT, LLVM_VARIANT, SCALAR_VARIANT.
MITSUBA_VARIANTS = ("scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb")
#: Plugins that must be there: what gicore/render.py's scene dicts name (the rgb values become srgb textures),
#: then what libmitsuba and the variant modules load by name (found with strings: the default sampler, film,
#: filter, BSDF and integrator, the textures behind colours, load_dict's merge of meshes, ...), and their own.
MITSUBA_PLUGINS = (
    "perspective hdrfilm box stratified rectangle area point path aov diffuse roughplastic srgb "
    "independent gaussian lanczos d65 regular irregular uniform merge depth bitmap obj orthographic isotropic volume"
).split()
#: Kept where the wheel has them: other common BSDFs, shapes, emitters, integrators, samplers, filters and
#: textures, so that a scene a little different from today's still loads. Not kept: media and phase functions,
#: polarisation, curves, ellipsoids, SDF grids, sunsky, hair, principled and measured BSDFs, the particle and
#: volumetric path tracers, spectral film and batch, irradiance and radiance meters.
MITSUBA_EXTRA_PLUGINS = (
    "plastic conductor roughconductor dielectric roughdielectric thindielectric twosided null mask blendbsdf "
    "bumpmap normalmap sphere cube disk cylinder ply serialized instance shapegroup constant directional spot envmap "
    "direct moment multijitter orthogonal ldsampler tent mitchell catmullrom thinlens checkerboard mesh_attribute "
    "blackbody rawconstant"
).split()
_MITSUBA_VARIANT_MODULE = re.compile(r"mitsuba/((?:scalar|llvm_ad|cuda_ad)_[a-z_]+)\.cpython-[^/]+\.so")
_MITSUBA_PLUGIN = re.compile(r"mitsuba/plugins/([^/]+)\.so")
_MITSUBA_DROPPED = re.compile(r"mitsuba/(include|cmake|pkgconfig|data/sunsky)/.*|mitsuba/data/srgb\.coeff")

OIDN_LIB = "pyoidn/oidn/lib/"
#: oidn/lib's loader roots: what pyoidn/capi.py dlopens, the device modules the core dlopens by name
#: (lib + OpenImageDenoise_device_<device> + .so.<version>) for the CPU and CUDA, and the tbbbind modules TBB
#: dlopens by soname. What they NEED follows (the core, libtbb.so.12).
_OIDN_ROOTS = re.compile(
    r"libOpenImageDenoise\.so|libOpenImageDenoise_device_(cpu|cuda)\.so\.[0-9.]+|libtbbbind(_[0-9]+_[0-9]+)?\.so\.[0-9]+"
)


@dataclass(frozen=True)
class Rule:
    """What a distribution's slim wheel holds."""

    #: whether an archive name outside ``lib_dir`` is kept
    keep: Callable[[str], bool]
    #: patterns (fnmatch's) each of which some file of the slim wheel must match
    required: tuple[str, ...]
    #: a folder whose shared libraries are kept as loader roots (``root``) or where a kept library NEEDs them
    lib_dir: str | None = None
    root: Callable[[str], bool] = lambda name: False


def _mitsuba_keep(name: str) -> bool:
    if _MITSUBA_DROPPED.fullmatch(name):
        return False
    if variant := _MITSUBA_VARIANT_MODULE.fullmatch(name):
        return variant.group(1) in MITSUBA_VARIANTS
    if plugin := _MITSUBA_PLUGIN.fullmatch(name):
        return plugin.group(1) in MITSUBA_PLUGINS + MITSUBA_EXTRA_PLUGINS
    return True


def _pyoidn_keep(name: str) -> bool:
    return not name.startswith(("pyoidn/oidn/bin/", OIDN_LIB))


RULES = {
    "mitsuba": Rule(
        _mitsuba_keep,
        (
            *(f"mitsuba/{v}.cpython-*.so" for v in MITSUBA_VARIANTS),
            "mitsuba/libmitsuba.so",
            *(f"mitsuba/plugins/{p}.so" for p in MITSUBA_PLUGINS),
        ),
    ),
    "pyoidn": Rule(
        _pyoidn_keep,
        (
            "pyoidn/capi.py",
            *(f"{OIDN_LIB}libOpenImageDenoise{lib}" for lib in (".so", "_core.so.*", "_device_cpu.so.*")),
            f"{OIDN_LIB}libOpenImageDenoise_device_cuda.so.*",
        ),
        OIDN_LIB,
        lambda name: bool(_OIDN_ROOTS.fullmatch(name)),
    ),
}


def elf_needed(data: bytes) -> list[str]:
    """The DT_NEEDED names of a 64-bit little-endian ELF file (the libraries the loader looks up for it), read from
    its SHT_DYNAMIC section and the string table that section links; [] for any other file."""
    if data[:4] != b"\x7fELF" or data[4:6] != b"\x02\x01":
        return []
    (shoff,) = struct.unpack_from("<Q", data, 0x28)
    shentsize, shnum = struct.unpack_from("<HH", data, 0x3A)
    # each: name, type, flags, addr, offset, size, link, info
    sections = [struct.unpack_from("<IIQQQQII", data, shoff + i * shentsize) for i in range(shnum)]
    needed = []
    for _, kind, _, _, offset, size, link, _ in sections:
        if kind != 6:  # SHT_DYNAMIC
            continue
        strtab = sections[link][4]
        for pos in range(offset, offset + size, 16):
            tag, value = struct.unpack_from("<qQ", data, pos)
            if tag == 0:  # DT_NULL ends the table
                break
            if tag == 1:  # DT_NEEDED: an offset into the string table
                start = strtab + value
                needed.append(data[start : data.index(b"\0", start)].decode())
    return needed


def _lib_closure(rule: Rule, files: dict[str, bytes]) -> set[str]:
    """The names of ``rule.lib_dir`` kept: its roots and, transitively, what kept files NEED from it. A library
    stored under several names is kept under each name asked for, which is one name in the wheels seen."""
    assert rule.lib_dir is not None
    lib = {n[len(rule.lib_dir) :]: n for n in files if n.startswith(rule.lib_dir) and "/" not in n[len(rule.lib_dir) :]}
    kept = {lib[n] for n in lib if rule.root(n)}
    todo = list(kept)
    while todo:
        for needed in elf_needed(files[todo.pop()]):
            if needed in lib and lib[needed] not in kept:
                kept.add(lib[needed])
                todo.append(lib[needed])
    return kept


def _check(name: str, rule: Rule, files: dict[str, bytes], kept: list[str]) -> None:
    """Fail where a required file, or a library that a kept one NEEDs and the wheel had, would be missing."""
    missing = [r for r in rule.required if not fnmatch.filter(kept, r)]
    had = {PurePosixPath(n).name for n in files}
    have = {PurePosixPath(n).name for n in kept}
    for n in kept:
        missing += [f"{lib} (NEEDED by {n})" for lib in elf_needed(files[n]) if lib in had and lib not in have]
    if missing:
        raise SystemExit(f"error: the slim {name} would lack {', '.join(missing)}: check the rules of {__file__}")


def _record_line(name: str, data: bytes) -> str:
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return f"{name},sha256={digest},{len(data)}"


def _slim_files(name: str, rule: Rule, files: dict[str, bytes]) -> dict[str, bytes]:
    """The files of the slim wheel ``name``, in the old order, with its new RECORD last."""
    dist_info = "-".join(name.split("-")[:2]) + ".dist-info"  # the wheel's name and version (a wheel may vendor more)
    record = f"{dist_info}/RECORD"
    in_lib = _lib_closure(rule, files) if rule.lib_dir else set()
    kept = [
        n
        for n in files
        if n in in_lib
        # the signatures of the old RECORD: no longer true
        or (rule.keep(n) and n not in (record, f"{dist_info}/RECORD.jws", f"{dist_info}/RECORD.p7s"))
    ]
    _check(name, rule, files, kept)
    contents = {n: files[n] for n in kept}
    lines = [*(_record_line(n, data) for n, data in contents.items()), f"{record},,"]
    return contents | {record: ("\n".join(lines) + "\n").encode()}


@dataclass(frozen=True)
class Rewritten:
    """A wheel rewritten: its sizes before and after (bytes), the files it holds and held, whether slimmed."""

    before: int
    after: int
    files: int
    files_before: int
    slimmed: bool


def rewrite_wheel(path: Path, compression: str = "lzma") -> Rewritten | None:
    """Rewrite the wheel at ``path`` in place: slimmed to its distribution's :data:`RULES` where it has some, else
    the same files (its RECORD still true) compressed with ``compression``; None where that would change nothing
    (no rule, and deflate, which wheels already use)."""
    rule = RULES.get(path.name.split("-")[0].lower().replace("_", "-"))
    if rule is None and compression == "deflate":
        return None
    with zipfile.ZipFile(path) as wheel:
        infos = {i.filename: i for i in wheel.infolist() if not i.is_dir()}
        files = {n: wheel.read(i) for n, i in infos.items()}
    contents = _slim_files(path.name, rule, files) if rule else files
    tmp = path.with_name(path.name + ".tmp")
    with zipfile.ZipFile(tmp, "w", allowZip64=True) as out:
        for n, data in contents.items():
            info = zipfile.ZipInfo(n, infos[n].date_time)
            info.external_attr = infos[n].external_attr  # the libraries' and tools' modes
            info.compress_type = COMPRESSION[compression]
            out.writestr(info, data, compresslevel=9)
    before = path.stat().st_size
    os.replace(tmp, path)
    return Rewritten(before, path.stat().st_size, len(contents), len(files), rule is not None)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("wheels", nargs="+", type=Path)
    parser.add_argument("--compression", choices=sorted(COMPRESSION), default="lzma")
    args = parser.parse_args(argv)
    others = []
    for path in args.wheels:
        done = rewrite_wheel(path, args.compression)
        if done is not None and done.slimmed:
            print(
                f"slim {path.name}: {done.before / MIB:.1f} MiB -> {done.after / MIB:.1f} MiB "
                f"({done.files} of {done.files_before} files, {args.compression})"
            )
        elif done is not None:
            others.append(done)
    if others:
        before, after = sum(d.before for d in others) / MIB, sum(d.after for d in others) / MIB
        print(f"the {len(others)} other wheels, same files, {args.compression}: {before:.1f} MiB -> {after:.1f} MiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
