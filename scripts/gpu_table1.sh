#!/usr/bin/env bash
# Table 1 on a GPU machine without network: install the project from carried wheels, then measure.
#
#   bash scripts/gpu_table1.sh [--dry-run | --stage-only] [--wheels DIR] [--out DIR]
#
# 1. Wheels: every wheel SHA256SUMS names (scripts/gpu_wheels.sh wrote it into each batch under --wheels, default
#    .gpu_wheels) is found whole or reassembled from its parts (cat NAME.whl.part.* in order) and its sha256
#    checked. A wheel whose parts have not all arrived is named (--stage-only: listed, exit 0; else exit 3).
# 2. Install, without network: each wheel whose distribution PYTHON's environment lacks, holds at an older
#    version, or is named in FORCE, with pip install --no-index --no-deps --find-links (what is there at the
#    wheel's version or newer is skipped); then the project itself, editable (its console scripts are what the
#    benches start). GL: .gl/*.deb, where carried, are unpacked first (the EGL loaders that
#    machine lacks).
# 3. Measure, into --out (default $OUT, the folder copied back from the GPU machine after the run):
#    - the GPU-only tests (pytest; a failure is reported in the log, not the end of the run);
#    - per resolution of RESOLUTIONS, bench latency --quick (profiles lan and wan) with the shipped model, or
#      MODEL_<R> where the shipped one is not at R (none: the shipped weights resized to R by
#      gigan_local.resize_cli, the network's cost at R);
#    - bench render --quick --renderers gl at every resolution;
#    - bench variants --quick (the server's bake on CUDA against the CPU's: SSIM >= 0.98 met or not; the CPU maps
#      from VARIANT_REFERENCE where carried, else baked here, which needs pyoidn; a failure is a line in the log);
#    - bench report;
#    - scripts/gpu_probe.py (nvJPEG decode and CUDA-GL interop upload against the host path; a failure is a line).
#    What comes back: provenance.txt (GPU name, driver, CUDA, the Mitsuba variant and inference backend chosen),
#    latency_table_<R>.md, variants.md, table1.md (bench report's results.md), probe.json, results.tar.gz (every
#    CSV, provenance JSON and figure of WORK, refreshed after each step), log.txt.
# --dry-run does step 1 in a temporary folder and prints what steps 2 and 3 would install and run.
#
# Settings (environment): PYTHON (python3), FORCE (distributions installed even where present), RESOLUTIONS
# (256 512), LATENCY_OPTIONS (more options of bench latency, e.g. --renderers gl), STEPS (which of step 3's parts
# run: tests latency render variants report probe, all by default), MODEL_<R>, STAGE (where wheels are reassembled: /tmp/gigan_gpu_wheels), GL_DEBS (.gl),
# VARIANT_REFERENCE (.gpu_reference: the --out of `bench variants --quick --variants cpu` made with pyoidn), WORK
# (the benches' own folders: /tmp/gigan_gpu_results).
set -euo pipefail

PYTHON=${PYTHON:-python3}
FORCE=${FORCE:-}
RESOLUTIONS=${RESOLUTIONS:-256 512}
LATENCY_OPTIONS=${LATENCY_OPTIONS:-}
STEPS=" ${STEPS:-tests latency render variants report probe} "
GL_DEBS=${GL_DEBS:-.gl}
VARIANT_REFERENCE=${VARIANT_REFERENCE:-.gpu_reference}
MODE=run
WHEELS=.gpu_wheels
DEST=${OUT:-}
while (($#)); do
  case "$1" in
    --dry-run) MODE=dry ;;
    --stage-only) MODE=stage ;;
    --wheels) WHEELS=${2:?--wheels needs a folder}; shift ;;
    --out) DEST=${2:?--out needs a folder}; shift ;;
    *) echo "error: unknown argument '$1': use --dry-run, --stage-only, --wheels DIR, --out DIR" >&2; exit 2 ;;
  esac
  shift
done
if [[ -z $DEST && $MODE != stage ]]; then echo "error: no output folder: pass --out DIR (or set OUT)" >&2; exit 2; fi
STAGE=${STAGE:-/tmp/gigan_gpu_wheels}
if [[ $MODE == dry ]]; then STAGE=$(mktemp -d); trap 'rm -rf "$STAGE"' EXIT; fi
if [[ $MODE == run ]]; then
  mkdir -p "$DEST"
  exec > >(tee "$DEST/log.txt") 2> >(tee -a "$DEST/log.txt" >&2)
fi

say() { echo "gpu_table1: $*"; }
step() { [[ $STEPS == *" $1 "* ]]; }  # whether STEPS names step 3's part $1
act() {  # run a command, or print it on a dry run
  if [[ $MODE == dry ]]; then echo "would run: $*"; else "$@"; fi
}

# -- 1. wheels ----------------------------------------------------------------------------------------------
sums=$(find "$WHEELS" -name SHA256SUMS -print -quit 2>/dev/null || true)
if [[ -z $sums ]]; then
  echo "error: no SHA256SUMS under $WHEELS: make the wheels with scripts/gpu_wheels.sh and carry a batch" >&2
  exit 2
fi
mkdir -p "$STAGE"
missing=()
while read -r sha name; do
  target="$STAGE/$name"
  if [[ -f $target ]] && sha256sum -c --status <<<"$sha  $target"; then continue; fi
  whole=$(find "$WHEELS" -name "$name" -type f -print -quit)
  mapfile -t parts < <(find "$WHEELS" -name "$name.part.*" -type f -printf '%f\t%p\n' | sort | cut -f2)
  how=whole
  if [[ -n $whole ]]; then
    cp "$whole" "$target"
  elif ((${#parts[@]})); then
    cat "${parts[@]}" >"$target"
    how="from ${#parts[@]} parts"
  fi
  if [[ -f $target ]] && sha256sum -c --status <<<"$sha  $target"; then
    say "wheel $name ready ($how)"
  else
    rm -f "$target"
    missing+=("$name (${#parts[@]} parts here)")
  fi
done <"$sums"
if ((${#missing[@]})); then
  for m in "${missing[@]}"; do say "incomplete: $m"; done
  if [[ $MODE == stage ]]; then say "carry the remaining batches, then run without --stage-only"; exit 0; fi
  echo "error: ${#missing[@]} wheels are incomplete (${missing[0]}, ...): carry the batches that hold their parts" >&2
  exit 3
fi
if [[ $MODE == stage ]]; then say "every wheel is here: run without --stage-only"; exit 0; fi

# -- 2. install -----------------------------------------------------------------------------------------------
to_install=()
normal() { tr '[:upper:]_' '[:lower:]-'; }  # a distribution name as pip compares it
forced=" $(normal <<<"$FORCE") "
installed() {  # the installed version of distribution $1, or nothing
  "$PYTHON" -c 'import importlib.metadata as m, sys; print(m.version(sys.argv[1]))' "$1" 2>/dev/null || true
}
at_least() {  # whether version $1 >= version $2
  "$PYTHON" -c 'import sys; from packaging.version import Version as V; sys.exit(V(sys.argv[1]) < V(sys.argv[2]))' "$1" "$2"
}
for wheel in "$STAGE"/*.whl; do
  dist=$(basename "$wheel" | cut -d- -f1 | normal)
  version=$(basename "$wheel" | cut -d- -f2)
  have=$(installed "$dist")
  if [[ $forced != *" $dist "* && -n $have ]] && at_least "$have" "$version"; then
    say "have $dist $have: skipped"
  else
    say "install $dist $version (have: ${have:-none})"
    to_install+=("$wheel")
  fi
done
if ((${#to_install[@]})); then
  act "$PYTHON" -m pip install --quiet --no-index --no-deps --find-links "$STAGE" "${to_install[@]}"
fi
act "$PYTHON" -m pip install --quiet --no-index --no-deps --no-build-isolation -e .
if compgen -G "$GL_DEBS/*.deb" >/dev/null; then
  for deb in "$GL_DEBS"/*.deb; do act dpkg -x "$deb" /; done
  act ldconfig
fi

# -- 3. measure -------------------------------------------------------------------------------------------------
BIN=$("$PYTHON" -c 'import sys, pathlib; print(pathlib.Path(sys.executable).parent)')
# The benches' folders stay outside --out (a run copies back a few files, not a tree); results.tar.gz is
# refreshed after every step, so a run stopped at its time limit still returns what finished.
RESULTS=${WORK:-/tmp/gigan_gpu_results}
act mkdir -p "$RESULTS"
pack() { act tar czf "$DEST/results.tar.gz" --exclude=gt_cache --exclude="store_*" -C "$RESULTS" .; }  # maps and GT renders stay
provenance() {
  nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv || echo "nvidia-smi: not found"
  nvidia-smi | grep -o 'CUDA Version: [0-9.]*' || true
  "$PYTHON" - <<'EOF'
import platform, torch
from gicore.mitsuba_variant import mitsuba_choice
from gigan_local.backend_choice import resolve_inference
from gicore.gl import gl_available
print("python", platform.python_version(), "torch", torch.__version__, "cuda", torch.version.cuda)
print("mitsuba", mitsuba_choice().variant, "denoiser", mitsuba_choice().denoiser)
print("inference (--inference auto)", resolve_inference("auto"))
if resolve_inference("auto") == "torch":
    from gigan_local.backend_choice import open_model
    from gigan_local.inference import DEFAULT_MODEL
    print("torch backend", open_model(DEFAULT_MODEL, "torch", threads=1, warmup=1).backend)
print("gl", gl_available())
EOF
}
if [[ $MODE == dry ]]; then echo "would write: $DEST/provenance.txt (nvidia-smi, python, torch, mitsuba, inference, gl)"; else
  provenance >"$DEST/provenance.txt" 2>&1
fi
# The tests that only a GPU runs (CUDA graph against eager kernels) and the GL warp against numpy on the GPU's own
# GL: a failure is reported in the log and the measurements go on.
gpu_tests=(tests/gigan_local/test_torch_backend.py tests/gigan_local/test_gl_warp.py)
if step tests && ! act timeout 180 "$PYTHON" -m pytest -q -p no:cacheprovider "${gpu_tests[@]}"; then
  say "GPU tests failed (above): the measurements go on"
fi
shipped=$("$PYTHON" -c 'from gigan_local.inference import DEFAULT_MODEL as m, read_model_json as r; print(m, r(m)["resolution"])')
read -r shipped_model shipped_res <<<"$shipped"
for res in $RESOLUTIONS; do
  step latency || break
  model_var="MODEL_$res"
  model=${!model_var:-}
  if [[ -z $model && $res == "$shipped_res" ]]; then model=$shipped_model; fi
  if [[ -z $model ]]; then  # the shipped weights at this side: its latency, not a model trained there
    act "$PYTHON" -m gigan_local.resize_cli "$(dirname "$shipped_model")" --resolution "$res" --out "$RESULTS/model_$res"
    model=$RESULTS/model_$res/$(basename "$shipped_model")
    say "latency at ${res}²: the shipped ${shipped_res}² model resized (set MODEL_$res for a model trained at ${res}²)"
  fi
  # shellcheck disable=SC2086  # LATENCY_OPTIONS is a list of options
  act "$BIN/bench" latency --quick --resolution "$res" --model "$model" $LATENCY_OPTIONS --out "$RESULTS/latency_$res"
  act cp "$RESULTS/latency_$res/latency.md" "$DEST/latency_table_$res.md"
  pack
done
if step render; then
  act "$BIN/bench" render --quick --renderers gl --gl-resolutions "${RESOLUTIONS// /,}" --out "$RESULTS/render_gl"
  pack
fi
if step variants; then
  variants=(--quick)
  if [[ -d $VARIANT_REFERENCE ]]; then variants+=(--variants cuda --reference "$VARIANT_REFERENCE"); fi
  if act "$BIN/bench" variants "${variants[@]}" --out "$RESULTS/variants"; then
    act cp "$RESULTS/variants/variants.md" "$DEST/variants.md"
  else
    say "bench variants failed (its error is above): no variants.md; the rest of the run goes on"
  fi
  pack
fi
if step report; then
  act "$BIN/bench" report --results "$RESULTS" --out "$RESULTS/report"
  act cp "$RESULTS/report/results.md" "$DEST/table1.md"
  pack
fi
# What a client path without host round trips would gain (nvJPEG, CUDA-GL interop): measured last, so that its
# failure costs the tables nothing.
if step probe && ! act timeout 180 "$PYTHON" scripts/gpu_probe.py --out "$DEST/probe.json"; then
  say "gpu_probe failed (above): the tables are complete"
fi
