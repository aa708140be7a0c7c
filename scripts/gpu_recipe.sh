#!/usr/bin/env bash
# The GPU recipe: render training sets with Mitsuba's CUDA variant (the five paper scenes and randomised scenes:
# shapes, colours, lights and environments drawn from a seed), then train GIGAN and its two rivals side by side on
# one CUDA GPU for the same wall time each, on the same data and with the same output encoding, and export them
# (ONNX, fp16).
#
# Nothing in the project needs a GPU; this is how the shipped model was trained on a GPU machine without network
# (see gigan_local/models/gigan_default/MODEL_CARD.md, which gives the settings of the shipped run: the five scenes
# alone, RANDOM_SCENES=0 DEMODULATE=0). Any CUDA machine with the project installed runs it:
#
#   MINUTES=13 bash scripts/gpu_recipe.sh
#
# then, to judge the exports on what users bring and on the five scenes (CPU or GPU):
#
#   bench quality --generalisation --models gigan=runs/gpu/exports/gigan/model_fp16.onnx --out results/generalisation
#   bench quality --models gigan=runs/gpu/exports/gigan/model_fp16.onnx --out results/quality
#
# Settings (environment): PYTHON (python3), WORK (runs/gpu: datasets/, runs/, exports/ below it),
# SCENES (the five paper scenes), TRAIN_FRAMES (400 per scene), VAL_FRAMES (10), SPP (512),
# DENOISE (0: the GT is the raw path-traced image; 1: OIDN-denoised, needs pyoidn), SEED (2: camera
# paths apart from the default data sets' seeds 0 and 1, which stay the CPU-rendered held-out frames),
# RANDOM_SCENES (400 randomised scenes; 0: none), RANDOM_FRAMES (8 training frames each, and one held-out),
# RANDOM_SEED (3: the draws and their camera paths; the held-out generalisation cases are shapes and colours no
# draw makes, on seed 7), DEMODULATE (1: every model sees and predicts albedo-demodulated shading, gigan-train
# --demodulate; 0: radiance), MINUTES (wall time per model), MODELS (gigan deep_illumination deep_shading),
# STAGES (render train export).
set -euo pipefail

PYTHON=${PYTHON:-python3}
WORK=${WORK:-runs/gpu}
SCENES=${SCENES:-lung_plane lung_cornell digestive_plane digestive_cornell vessels_plane}
TRAIN_FRAMES=${TRAIN_FRAMES:-400}
VAL_FRAMES=${VAL_FRAMES:-10}
SPP=${SPP:-512}
DENOISE=${DENOISE:-0}
SEED=${SEED:-2}
RANDOM_SCENES=${RANDOM_SCENES:-400}
RANDOM_FRAMES=${RANDOM_FRAMES:-8}
RANDOM_SEED=${RANDOM_SEED:-3}
DEMODULATE=${DEMODULATE:-1}
MINUTES=${MINUTES:-6}
MODELS=${MODELS:-gigan deep_illumination deep_shading}
STAGES=${STAGES:-render train export}
export GIGAN_MITSUBA_VARIANT=${GIGAN_MITSUBA_VARIANT:-cuda}
for stage in $STAGES; do
  case "$stage" in render | train | export) ;; *) echo "error: unknown stage '$stage'; STAGES takes render, train, export (space-separated)" >&2; exit 2 ;; esac
done
mkdir -p "$WORK"

# Per model: the paper's settings (batch 8, lr 2e-4, n_critic 1) on whole 256² frames with a 1x1
# bottleneck (n_down 8, as pix2pix's unet_256 runs), width 16 for the CPU client's 25 ms budget.
# GIGAN up-samples by resize (its one departure from the paper: no checkerboard); the rivals keep their own designs.
model_args() {
  case "$1" in
    gigan) echo "--model gigan --upsample resize --n-down 8" ;;
    deep_illumination) echo "--model deep_illumination --n-down 8" ;;
    deep_shading) echo "--model deep_shading" ;;
    *) echo "error: unknown model '$1'; MODELS takes gigan, deep_illumination, deep_shading" >&2; return 2 ;;
  esac
}
for model in $MODELS; do model_args "$model" >/dev/null || exit 2; done

# Background jobs: wait for all of them, report every failure with its log, and stop the rest on Ctrl-C.
pids=()
trap 'kill "${pids[@]}" 2>/dev/null' INT TERM
wait_all() {  # $1: what the jobs were; the logs are named in $WORK
  local failed=0
  for pid in "${pids[@]}"; do wait "$pid" || failed=1; done
  pids=()
  if [[ $failed == 1 ]]; then echo "error: a $1 job failed; see its log in $WORK" >&2; exit 1; fi
}

datasets=()
for scene in $SCENES; do datasets+=("$WORK/datasets/$scene"); done
random_root="$WORK/datasets/random"

if [[ " $STAGES " == *" render "* ]]; then
  denoise_flag=$([[ "$DENOISE" == 1 ]] && echo --denoise || echo --no-denoise)
  for scene in $SCENES; do  # one process per scene: each has its own CUDA context, and the GPU overlaps them
    "$PYTHON" -m gicore.dataset_cli "$scene" --out "$WORK/datasets" --train "$TRAIN_FRAMES" --val "$VAL_FRAMES" \
      --resolution 256 --spp "$SPP" "$denoise_flag" --seed "$SEED" >"$WORK/render_$scene.log" 2>&1 &
    pids+=($!)
  done
  if [[ "$RANDOM_SCENES" -gt 0 ]]; then  # its card: $random_root/random_scenes.md
    "$PYTHON" -m gicore.dataset_cli --random "$RANDOM_SCENES" --out "$random_root" --train "$RANDOM_FRAMES" \
      --val 1 --resolution 256 --spp "$SPP" "$denoise_flag" --seed "$RANDOM_SEED" --workers 4 \
      >"$WORK/render_random.log" 2>&1 &
    pids+=($!)
  fi
  wait_all render
fi

if [[ " $STAGES " == *" train "* ]]; then
  if [[ "$RANDOM_SCENES" -gt 0 ]]; then  # scenes 0 .. RANDOM_SCENES - 1 of the seed, as the render stage drew them
    for ((i = 0; i < RANDOM_SCENES; i++)); do
      folder=$(printf '%s/random%s_%04d' "$random_root" "$RANDOM_SEED" "$i")
      [[ -f "$folder/meta.json" ]] || { echo "error: $folder is missing; run STAGES=render first" >&2; exit 2; }
      datasets+=("$folder")
    done
  fi
  encoding=$([[ "$DEMODULATE" == 1 ]] && echo --demodulate || echo --no-demodulate)
  for model in $MODELS; do  # side by side: the same minutes of the same GPU for each
    read -ra args <<<"$(model_args "$model") $encoding"
    OMP_NUM_THREADS=4 "$PYTHON" -m gigan_local.train_cli "${datasets[@]}" --out "$WORK/runs/$model" "${args[@]}" \
      --ngf 16 --batch-size 8 --lr 2e-4 --epochs 100000 --max-minutes "$MINUTES" --max-val-frames 10 --device cuda --no-progress \
      >"$WORK/train_$model.log" 2>&1 &
    pids+=($!)
  done
  wait_all train
fi

if [[ " $STAGES " == *" export "* ]]; then
  for model in $MODELS; do
    "$PYTHON" -m gigan_local.export_cli "$WORK/runs/$model" --out "$WORK/exports/$model" --fp16
  done
fi
