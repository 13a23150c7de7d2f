#!/usr/bin/env bash
# Rebuild the FGD autoencoder that ships with the package (src/facecapges/assets/fgd/beat-upper-body/), what
# `facecapges eval` measures FGD with when a style carries none of its own (e.g. every motion-matching style).
#   Data: BEAT speaker 2 "scott" only (CC BY-NC 4.0): the BEAT take 2_scott_0_1_1 (BVH) and the BEAT2 take
#   2_scott_0_2_2 (SMPL-X npz, converted by facecapges.data.beat2), the first 80 % of each take only
#   (`fgd-train --holdout-tail`: frames before each clip's holdout_from; the last 20 % is never read).
#   Then the card's figures (held-out reconstruction error, FGD sanity controls) into $WORK/card.json by
#   scripts/fgd_card_figures.py. 200 epochs (not the recipe's 400: one SGD step an epoch on these 143
#   windows costs ~1.5 s of CPU; EPOCHS=400 doubles it): ~10 min of CPU, 30-45 min niced on a busy 2-core box.
set -euo pipefail
cd "$(dirname "$0")/.."
FC=${FC:-.venv/bin/facecapges}
PY=${PY:-.venv/bin/python}
WORK=${WORK:-build/fgd}
OUT=src/facecapges/assets/fgd/beat-upper-body
BEAT=../shared/data/beat
BEAT2=../shared/data/beat2
mkdir -p "$WORK/beat2-root/smplxflame_30" "$WORK/beat2-root/wave16k" "$OUT"
ln -sf "$(realpath "$BEAT/2_scott_0_1_1.bvh")" "$(realpath "$BEAT/2_scott_0_1_1.wav")" "$WORK/beat2-root/"
ln -sf "$(realpath "$BEAT2/2_scott_0_2_2.npz")" "$WORK/beat2-root/smplxflame_30/"
ln -sf "$(realpath "$BEAT/2_scott_0_2_2.wav")" "$WORK/beat2-root/wave16k/"
nice -n 10 $FC prepare "$WORK/beat2-root" --out "$WORK/cache" --force --quiet
nice -n 10 $FC fgd-train --cache "$WORK/cache" --speaker 2 --split all --holdout-tail --out "$OUT" --seed 0 --epochs ${EPOCHS:-200} --force
nice -n 10 $PY scripts/fgd_card_figures.py --cache "$WORK/cache" --fgd "$OUT" --out "$WORK/card.json"
echo "installed into $OUT; the card's figures in $WORK/card.json (copy them into $OUT/README.md)"
