#!/usr/bin/env bash
# Rebuild the shipped motion-matching style beat2-scott-mm from ../shared (BEAT speaker 2 "scott"):
#   BEAT 2_scott_0_1_1 (BVH) + BEAT2 2_scott_0_2_2 (SMPL-X npz, converted by facecapges.data.beat2),
#   each with its wav; the first 80 % of each take and their mirror images (the last 20 % never read).
# Then its figures: validation (database and predictor from [0, 0.64 T), scored on [0.64 T, 0.8 T))
# and held-out (from [0, 0.8 T), scored on [0.8 T, T)) by scripts/matching_validate.py, into
# build/matching-style/*.json for the model card. A few minutes on an idle 2-core CPU.
set -euo pipefail
cd "$(dirname "$0")/.."
FC=.venv/bin/facecapges
PY=.venv/bin/python
WORK=${WORK:-build/matching-style}
STYLES=src/facecapges/assets/styles
BEAT=../shared/data/beat
BEAT2=../shared/data/beat2
mkdir -p "$WORK" "$STYLES"
TAKES=(--take "$BEAT/2_scott_0_1_1.bvh" "$BEAT/2_scott_0_1_1.wav" --take "$BEAT2/2_scott_0_2_2.npz" "$BEAT/2_scott_0_2_2.wav")
$FC styles build beat2-scott-mm "${TAKES[@]}" --out "$STYLES/beat2-scott-mm.safetensors" --force
if [ -z "${NO_FIGURES:-}" ]; then
    V=(scripts/matching_validate.py "${TAKES[@]}" --skeleton-from "$BEAT/2_scott_0_1_1.bvh,$BEAT/2_scott_0_1_1.wav" --starts 4)
    $PY "${V[@]}" --predictor > "$WORK/validation.json"
    $PY "${V[@]}" --predictor --heldout > "$WORK/heldout.json"
    $PY "${V[@]}" --network beat2-scott-demo > "$WORK/network-validation.json"
    $PY "${V[@]}" --network beat2-scott-demo --heldout > "$WORK/network-heldout.json"
    $PY scripts/matching_card_figures.py "$STYLES/beat2-scott-mm.md" \
        "matching, validation=$WORK/validation.json" \
        "network beat2-scott-demo, validation (it trained on 1_1's validation frames)=$WORK/network-validation.json" \
        "matching, held-out=$WORK/heldout.json" "network beat2-scott-demo, held-out=$WORK/network-heldout.json"
fi
