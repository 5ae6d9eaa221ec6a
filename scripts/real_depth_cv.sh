#!/usr/bin/env bash
# Leave-scene-out validation of the estimator on real pictures, through the product's own commands:
# 5 fold models by `rvr train --real ... --real-exclude <the fold's scenes>`, then
# `rvr eval-estimator --real-set ... --weights-per-scene folds.json` scores every scene with the
# model that never saw it. Also trains the all-scenes model (what ships) and scores Motorcycle
# (never trained on) with it.
#
# Usage: scripts/real_depth_cv.sh OUT [ITERATIONS]     (about 10 min a fold on 2 cores)
# Environment: THREADS (torch threads, 2), START (weights to fine-tune), REAL (the data),
#   EXTRA (more training flags, e.g. "--row-prior --lr 3e-4"), TRAIN_ONLY (all | disparity-head:
#   the grid head alone learns, E stays bit-identical; via rvr train --train-only),
#   FOLDS (which fold models to train and score, e.g. "0 1 2"; default all five; a subset scores
#   only those folds' scenes), ALL (0: skip the all-scenes model and Motorcycle).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:?usage: scripts/real_depth_cv.sh OUT [ITERATIONS]}
ITER=${2:-1000}
REAL=${REAL:-../shared/data/real_depth}
START=${START:-rvr_addon/estimate/weights/estimator.pt}
RVR=.venv/bin/rvr
FLAGS=(--iterations "$ITER" --batch 4 --crop 160 --min-scale 0.45 --whole-frame 0.3 --inference-max-pixels 57600
       --threads "${THREADS:-2}" -q)
read -r -a EXTRA_FLAGS <<< "${EXTRA:-}"
FLAGS+=("${EXTRA_FLAGS[@]}")
TRAIN=("$RVR" train)
[ "${TRAIN_ONLY:-all}" = all ] || TRAIN=("$RVR" train --train-only "$TRAIN_ONLY")
FOLDS=${FOLDS:-0 1 2 3 4}
mkdir -p "$OUT"
# the folds: scenes round robin over their sorted names (rvr_addon.estimate.real_data.scene_folds)
.venv/bin/python - "$REAL" "$OUT" "$FOLDS" <<'PY'
import json, sys
from rvr_addon.estimate.real_data import find_real_pictures, scene_folds
pics = find_real_pictures(sys.argv[1])
folds = scene_folds(pics, 5)
chosen = [int(k) for k in sys.argv[3].split()]
json.dump(folds, open(f"{sys.argv[2]}/folds.json", "w"), indent=1)
json.dump({s: f"fold{k}/estimator.pt" for k, fold in enumerate(folds) for s in fold if k in chosen},
          open(f"{sys.argv[2]}/weights_per_scene.json", "w"), indent=1)
PY
for k in $FOLDS; do
  [ -f "$OUT/fold$k/estimator.pt" ] && continue
  mapfile -t EXCL < <(.venv/bin/python -c "import json,sys; print('\n'.join(json.load(open('$OUT/folds.json'))[$k]))")
  ARGS=(); for s in "${EXCL[@]}"; do ARGS+=(--real-exclude "$s"); done
  "${TRAIN[@]}" --real "$REAL" --init-from "$START" -o "$OUT/fold$k" "${FLAGS[@]}" "${ARGS[@]}"
done
if [ "${ALL:-1}" = 0 ]; then  # folds only: scenes outside them are scored by START (read only the folds')
  "$RVR" eval-estimator --weights "$START" --real-set "$REAL" \
    --weights-per-scene "$OUT/weights_per_scene.json" -o "$OUT/report" --force -q
  echo "fold figures: $OUT/report/summary.json (per view in its README; only the scenes of folds $FOLDS count)"
  exit 0
fi
[ -f "$OUT/all/estimator.pt" ] || "${TRAIN[@]}" --real "$REAL" --init-from "$START" -o "$OUT/all" "${FLAGS[@]}"
"$RVR" eval-estimator --weights "$OUT/all/estimator.pt" --real-set "$REAL" \
  --weights-per-scene "$OUT/weights_per_scene.json" --motorcycle -o "$OUT/report" --force
echo "leave-scene-out figures: $OUT/report/summary.json (estimate.real.middlebury.*); Motorcycle with $OUT/all"
