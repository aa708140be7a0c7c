#!/usr/bin/env bash
# Wheels for a GPU machine without network, fetched HERE (with network); scripts/gpu_table1.sh installs them.
#
#   bash scripts/gpu_wheels.sh [--from DIR] [OUT]        (OUT: .gpu_wheels, which git ignores)
#
# Downloads, for CPython PY_TAG (312: the GPU image's Python 3.12) on manylinux x86_64, each of PACKAGES (the
# project's dependencies, direct or not, that the GPU image lacks or may hold too old) at the version PYTHON's
# environment holds, without dependencies (each one needed is named). --from DIR
# takes the wheels from DIR instead of downloading them. Then (SLIM=1, the default) scripts/gpu_slim_wheel.py
# rewrites them in place: mitsuba's and pyoidn's cut to the variants, plugins and OIDN devices the project loads
# (it prints each one's size before and after), and all of them compressed with SLIM_ZIP (lzma: two batches where
# deflate takes three; pip then needs Python's lzma module). A wheel over PART_MIB is split into parts of PART_MIB
# (NAME.whl.part.aa, .ab, ...); every file then goes into one of OUT/batch1, OUT/batch2, ..., each small enough to
# travel with the repository in one run on the GPU machine (CARRY_MIB in all, minus the tree's measured size and MARGIN_MIB),
# and OUT/SHA256SUMS (each whole wheel's sha256) is copied into every batch, so that gpu_table1.sh can check each
# wheel it reassembles. A wheel split across batches arrives over several runs on the same machine.
#
# Settings (environment): PYTHON (.venv/bin/python), PY_TAG (312), PACKAGES, CARRY_MIB (64), MARGIN_MIB (2),
# PART_MIB (the smaller of 45 and what one batch may hold), SLIM (1; 0: the wheels as published), SLIM_ZIP (lzma
# or deflate).
set -euo pipefail

PYTHON=${PYTHON:-.venv/bin/python}
PY_TAG=${PY_TAG:-312}
# What the image lacks, then what it has but perhaps older than these need (gpu_table1.sh installs those only then):
# the project's build backend, and the server's typing and HTTP stack (FastAPI imports opentelemetry-api). pyoidn
# denoises on the GPU where the driver has no OptiX denoiser weights (gicore.mitsuba_variant).
PACKAGES=${PACKAGES:-mitsuba drjit fastapi starlette uvicorn httptools pydantic pydantic-core pydantic-settings \
python-dotenv annotated-types typing-inspection trimesh zstandard openexr moderngl glcontext fast-simplification \
pyoidn cffi pycparser opentelemetry-api setuptools typing-extensions anyio click h11 annotated-doc}
CARRY_MIB=${CARRY_MIB:-64}
MARGIN_MIB=${MARGIN_MIB:-2}
SLIM=${SLIM:-1}
SLIM_ZIP=${SLIM_ZIP:-lzma}
FROM=""
if [[ ${1:-} == --from ]]; then FROM=${2:?--from needs a folder}; shift 2; fi
OUT=${1:-.gpu_wheels}
MIB=$((1024 * 1024))

# what a run copies of the tree to the GPU machine; a tracked file deleted here (not yet committed) is not copied
tree_bytes=$(git ls-files -co --exclude-standard -z | { du -cb --files0-from=- 2>/dev/null || true; } | tail -1 | cut -f1)
budget=$((CARRY_MIB * MIB - tree_bytes - MARGIN_MIB * MIB))
if ((budget < MIB)); then
  echo "error: the repository's tree is $((tree_bytes / MIB)) MiB, leaving no room for wheels in a ${CARRY_MIB} MiB run: ignore what need not travel" >&2
  exit 2
fi
PART_MIB=${PART_MIB:-$((budget / MIB < 45 ? budget / MIB : 45))}
part_bytes=$((PART_MIB * MIB))
if ((part_bytes > budget)); then
  echo "error: PART_MIB=$PART_MIB is over the $((budget / MIB)) MiB a batch may hold: lower it" >&2
  exit 2
fi

rm -rf "$OUT"
mkdir -p "$OUT/wheels" "$OUT/files"
if [[ -n $FROM ]]; then
  cp "$FROM"/*.whl "$OUT/wheels/"
else
  pins=()
  for name in $PACKAGES; do
    version=$("$PYTHON" -c 'import importlib.metadata as m, sys; print(m.version(sys.argv[1]))' "$name") || {
      echo "error: $name is not installed in $PYTHON's environment: install the project there first (scripts/setup.sh)" >&2
      exit 2
    }
    pins+=("$name==$version")
  done
  platforms=(--platform manylinux2014_x86_64 --platform manylinux1_x86_64)
  for n in $(seq 17 39); do platforms+=(--platform "manylinux_2_${n}_x86_64"); done
  "$PYTHON" -m pip download --quiet --no-deps --only-binary=:all: --python-version "$PY_TAG" --implementation cp \
    "${platforms[@]}" -d "$OUT/wheels" "${pins[@]}"
fi

if [[ $SLIM != 0 ]]; then
  slim_before=$(du -cb "$OUT"/wheels/*.whl | tail -1 | cut -f1)
  "$PYTHON" "$(dirname "$0")/gpu_slim_wheel.py" --compression "$SLIM_ZIP" "$OUT"/wheels/*.whl
  slim_after=$(du -cb "$OUT"/wheels/*.whl | tail -1 | cut -f1)
  echo "all wheels: $((slim_before / MIB)) MiB -> $((slim_after / MIB)) MiB (SLIM=0 keeps them as published)"
fi
(cd "$OUT/wheels" && sha256sum -- *.whl) >"$OUT/SHA256SUMS"
for wheel in "$OUT"/wheels/*.whl; do
  if (($(stat -c %s "$wheel") > part_bytes)); then
    split -b "$part_bytes" "$wheel" "$OUT/files/$(basename "$wheel").part."
  else
    cp "$wheel" "$OUT/files/"
  fi
done

# First fit, largest file first: each file into the first batch it fits in.
declare -a used=()
while read -r size file; do
  for ((b = 0; ; b++)); do
    if ((${used[b]:-0} + size <= budget)); then
      mkdir -p "$OUT/batch$((b + 1))"
      mv "$file" "$OUT/batch$((b + 1))/"
      used[b]=$((${used[b]:-0} + size))
      break
    fi
  done
done < <(find "$OUT/files" -type f -printf '%s %p\n' | sort -rn)
rmdir "$OUT/files"
for ((b = 0; b < ${#used[@]}; b++)); do cp "$OUT/SHA256SUMS" "$OUT/batch$((b + 1))/"; done

echo "$(wc -l <"$OUT/SHA256SUMS") wheels in ${#used[@]} batches of at most $((budget / MIB)) MiB (the tree: $((tree_bytes / MIB)) MiB):"
for ((b = 0; b < ${#used[@]}; b++)); do
  echo "  $OUT/batch$((b + 1)): $((used[b] / MIB)) MiB, $(find "$OUT/batch$((b + 1))" -name '*.whl*' | wc -l) files"
done
echo "Each run on the GPU machine copies one batch; every run but the last: bash scripts/gpu_table1.sh --stage-only --wheels $OUT"
