#!/usr/bin/env bash
# The RGBD-HDR estimator's training data (issue 4), as used for the shipped weights
# (rvr_addon/estimate/weights/MODEL.md). Every clip is resumable: run the script again after an
# interruption. Seeds never overlap the held-out evaluation clips (1001-1005).
#
#   scripts/estimator_data.sh [DATA_DIR] [N_DEEP]
#
# DATA_DIR/train  clips WITH training passes (Cycles shallow-DOF pairs, aperture and focal
#                 triplets on every frame): photo style, 8 frames each. Seeds 3001-3004 with the
#                 default camera tilt, 3101.. tilted down (the floor recedes, as in much real
#                 footage). ~3-7 min a clip on this 2-core machine.
# DATA_DIR/deep   ground-truth-only clips (--no-dof: the deep pass with exact disparity and HDR,
#                 no DOF passes; `rvr train` uses them for its supervised terms, kind "gt"):
#                 photo style, 6 frames each, seeds 4001.. (even seeds tilted down). ~40 s a clip.
# DATA_DIR/procedural/proc2, proc3  procedural scenes (`rvr procedural`, no Cycles: ~0.7 s a frame
#                 on one core) as the shipped weights used them: 2,105 frames of generator 2
#                 (rooms and streets, seed 2) and 1,294 of generator 3 (a third close-ups, seed 4),
#                 textured with pieces of ../shared/data's Sintel frames, the harness's texture
#                 cache (frames of the real clips, written by the `generate` runs above) and
#                 scikit-image's samples; proc3 also with $OCV_PHOTOS when it is set: a folder of
#                 the 21 photographs of OpenCV's samples/data listed in MODEL.md (from
#                 `pip download --no-deps --no-binary :all: opencv-python==4.11.0.86`).
#
# Then, e.g. (MODEL.md has the exact commands of the shipped weights):
#   rvr train --data DATA_DIR/procedural --data DATA_DIR/deep --data DATA_DIR/train -o RUN \
#             --procedural-share 0.6 --gt-share 0.75 --ignore-prints --crop 160 \
#             --inference-max-pixels 57600 --threads 1 --iterations 20000
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
DATA=${1:-out/estimator_data}
N_DEEP=${2:-600}
N_TRAIN=${N_TRAIN:-40}

gen() {  # gen OUT ARGS...: one clip, skipped when complete
  local out=$1; shift
  [[ -f "$out/.complete" ]] && return 0
  if nice -n 10 "$PY" -m sintel_eval generate --script random --size 320x180 --style photo -q -o "$out" "$@"; then
    touch "$out/.complete"
  else
    echo "clip $out failed; re-run to resume it" >&2
  fi
}

for seed in 3001 3002 3003 3004; do
  gen "$DATA/train/clip_$seed" --seed "$seed" --frames 8 --train-every 1
done
for ((i = 0; i < N_TRAIN; i++)); do
  seed=$((3101 + i))
  gen "$DATA/train/clip_$seed" --seed "$seed" --frames 8 --train-every 1 --tilt=-14,1
done
for ((i = 0; i < N_DEEP; i++)); do
  seed=$((4001 + i))
  if ((seed % 2 == 0)); then tilt=(--tilt=-16,0); else tilt=(); fi
  gen "$DATA/deep/clip_$seed" --seed "$seed" --frames 6 --no-dof "${tilt[@]}"
done
TEXTURE_CACHE=${RVR_TEXTURE_CACHE:-$HOME/.cache/rvr-laaf/textures}
textures=(--textures ../shared/data/sintel_frames)
[[ -d "$TEXTURE_CACHE/frames" ]] && textures+=(--textures "$TEXTURE_CACHE/frames")
nice -n 10 "$PY" -m rvr_addon procedural -o "$DATA/procedural/proc2" --frames 2105 --seed 2 --generator 2 \
  "${textures[@]}"
[[ -n "${OCV_PHOTOS:-}" ]] && textures+=(--textures "$OCV_PHOTOS")
nice -n 10 "$PY" -m rvr_addon procedural -o "$DATA/procedural/proc3" --frames 1294 --seed 4 --generator 3 \
  "${textures[@]}"
