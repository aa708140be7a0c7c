#!/usr/bin/env bash
# The runs behind docs/results.md: every bench into one results folder, then `bench report` renders the folder
# into docs/results.md (tables, the command of each, figures copied into docs/figures/) and a dashboard.
#   bash scripts/results.sh                 # Table 1 and Table 2 at their full presets, the other benches --quick
#   FULL=all bash scripts/results.sh        # every bench at its full preset (hours on 2 cores)
#   OUT=results/mine bash scripts/results.sh
# A bench that fails is named at the end and its block in docs/results.md says its CSV is missing; the others
# still run. Each bench resumes nothing: rerun the script, or run the one bench by hand with the same --out.
set -uo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-results/docs}
FULL=${FULL:-tables}
BENCH=.venv/bin/bench
failed=()

run() {  # run NAME FULL_BY_DEFAULT [OPTIONS...]: one bench into $OUT/NAME, --quick unless it runs full
  local name=$1 full=$2
  shift 2
  local preset=(--quick)
  if [ "$FULL" = all ] || [ "$full" = yes ]; then preset=(); fi
  echo "results.sh: bench $name ${preset[*]} $*" >&2
  if ! "$BENCH" "$name" "${preset[@]}" "$@" --out "$OUT/$name"; then failed+=("$name"); fi
}

run latency yes --renderers gl
run storage yes
run warp no
run frequency no
run fov no
run quality no
run service no
run load no
run web no
run prefetch no
run stability no
run scaling no
run convergence no
run pareto no --from-dir "$OUT"
echo "results.sh: network-sim selftest" >&2
.venv/bin/network-sim selftest --out "$OUT/netself" || failed+=(network-selftest)
"$BENCH" report --results "$OUT" --ignore pareto/pareto_runs --out "$OUT/report" --readme docs/results.md \
  --figures docs/figures || failed+=(report)
if [ ${#failed[@]} -gt 0 ]; then
  echo "results.sh: failed: ${failed[*]} (their blocks in docs/results.md say the CSV is missing)" >&2
  exit 1
fi
echo "results.sh: docs/results.md and $OUT/report/report.html written" >&2
