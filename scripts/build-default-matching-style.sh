#!/usr/bin/env bash
# Rebuild the shipped motion-matching style beat2-scott-mm from ../shared (BEAT speaker 2 "scott"):
#   BEAT 2_scott_0_1_1 (BVH) + BEAT2 2_scott_0_2_2 (SMPL-X npz, converted by facecapges.data.beat2),
#   each with its wav; the first 80 % of each take and their mirror images (the last 20 % never read).
# Then its figures, into build/matching-style/ for the model card: validation (database and predictor
# from [0, 0.64 T), scored on [0.64 T, 0.8 T)) by scripts/matching_validate.py; held-out (the style from
# [0, 0.8 T), scored on [0.8 T, T)) and unseen speech by scripts/style_report.py, tabled by
# scripts/card_heldout_table.py; issue #38's conversation figures by scripts/conversation_report.py. A few
# minutes on an idle 2-core CPU.
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
    # validation (choices only): database and predictor from [0, 0.64 T), scored on [0.64 T, 0.8 T)
    $PY scripts/matching_validate.py "${TAKES[@]}" --skeleton-from "$BEAT/2_scott_0_1_1.bvh,$BEAT/2_scott_0_1_1.wav" \
        --starts 2 --predictor > "$WORK/validation.json"
    # held-out 20 % and unseen speech, the metrics of `facecapges eval`, beside the network style
    mkdir -p "$WORK/beat2-root/smplxflame_30" "$WORK/beat2-root/wave16k"
    ln -sf "$(realpath "$BEAT/2_scott_0_1_1.bvh")" "$(realpath "$BEAT/2_scott_0_1_1.wav")" "$WORK/beat2-root/"
    ln -sf "$(realpath "$BEAT2/2_scott_0_2_2.npz")" "$WORK/beat2-root/smplxflame_30/"
    ln -sf "$(realpath "$BEAT/2_scott_0_2_2.wav")" "$WORK/beat2-root/wave16k/"
    $FC prepare "$WORK/beat2-root" --out "$WORK/cache" --force
    for st in beat2-scott-mm beat2-scott-demo; do
        $PY scripts/style_report.py --checkpoint "$STYLES/$st.safetensors" --cache "$WORK/cache" --speaker 2 \
            --audio "$BEAT/2_scott_0_4_4.wav" --out "$WORK/$st.report.json"
    done
    $PY scripts/card_heldout_table.py "matching beat2-scott-mm=$WORK/beat2-scott-mm.report.json" \
        "network beat2-scott-demo=$WORK/beat2-scott-demo.report.json" > "$WORK/heldout-table.md"
    # issue #38: the conversation clips (pauses of zeros, room tone, keyboard, music, a far voice; ZEGGS half
    # silent; built from ../shared at run time) and the held-out stretches' #38 figures, both styles
    for st in beat2-scott-mm beat2-scott-demo; do
        $PY scripts/conversation_report.py --checkpoint "$STYLES/$st.safetensors" --out "$WORK/$st.conversation.json"
    done
    $PY scripts/conversation_report.py --table "matching=$WORK/beat2-scott-mm.conversation.json" \
        "network=$WORK/beat2-scott-demo.conversation.json" > "$WORK/conversation-table.md"
    echo "figures in $WORK (the model card's tables come from validation.json and heldout-table.md)"
fi
