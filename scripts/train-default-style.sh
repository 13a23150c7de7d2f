#!/usr/bin/env bash
# Rebuild the shipped network style beat2-scott-demo from ../shared and install it into assets/styles:
#   BEAT speaker 2 "scott" only (CC BY-NC 4.0): BEAT 2_scott_0_1_1 (BVH) + BEAT2 2_scott_0_2_2 (SMPL-X npz,
#   converted by facecapges.data.beat2), each with its wav; trained from random weights on the first 80 %
#   of each take (configs/demo-beat2-scott.yaml, train.holdout_fraction 0.2: the last 20 % never read).
# prepare -> face off -> train -> figures on the held-out 20 % and unseen audio (scripts/style_report.py).
# Needs ../shared beside the repo and `make setup` done. The model card gives the measured wall time.
# RESUME=1 continues an interrupted run exactly.
#
# ONLY=zeggs instead builds a style of the ZEGGS speaker for your own use from YOUR copy of ZEGGS
# (ZEGGS=DIR with the retargetable take, ZEGGS9=DIR with the 9-joint takes; default ../shared/data):
# configs/zeggs.yaml, installed by `facecapges styles install` into your styles folder
# ($FACECAPGES_STYLES, else ~/.local/share/facecapges/styles) as `zeggs-speech`. ZEGGS is CC BY-NC-ND
# 4.0: a model trained on it is an adapted work that may not be shared — it is never written into the
# package (src/facecapges/assets) and must never be committed or shipped.
set -euo pipefail
cd "$(dirname "$0")/.."
FC=.venv/bin/facecapges
PY=.venv/bin/python
WORK=${WORK:-build/default-style}
STYLES=src/facecapges/assets/styles
BEAT=../shared/data/beat
BEAT2=../shared/data/beat2
mkdir -p "$WORK"

if [ "${ONLY:-}" = zeggs ]; then
    ZEGGS=${ZEGGS:-../shared/data/zeggs}
    ZEGGS9=${ZEGGS9:-../shared/data/zeggs9}
    if [ -z "${RESUME:-}" ]; then
        # the BEAT take is the target skeleton the ZEGGS motion is retargeted onto (speaker 100 trains)
        $FC prepare "$BEAT" --out "$WORK/cache-zeggs" --speakers 2 --mocap "$ZEGGS" --joints9 "$ZEGGS9" --force --quiet
        $FC train --cache "$WORK/cache-zeggs" --speaker 100 --split all --out "$WORK/zeggs-speech" \
            --config configs/zeggs.yaml --force
    else
        $FC train --cache "$WORK/cache-zeggs" --speaker 100 --out "$WORK/zeggs-speech" --resume
    fi
    $FC styles install "$WORK/zeggs-speech" --name zeggs-speech --force
    $PY scripts/style_report.py --checkpoint "$WORK/zeggs-speech/model.safetensors" --cache "$WORK/cache-zeggs" \
        --speaker 100 --audio "$BEAT/2_scott_0_2_2.wav" --out "$WORK/zeggs-speech.report.json"
    echo "installed zeggs-speech into your styles folder (not the package); figures in $WORK/zeggs-speech.report.json"
    exit 0
fi

if [ -z "${RESUME:-}" ]; then
    # BEAT2's layout (smplxflame_30/*.npz beside wave16k/*.wav), as scripts/build-default-matching-style.sh
    mkdir -p "$WORK/beat2-root/smplxflame_30" "$WORK/beat2-root/wave16k"
    ln -sf "$(realpath "$BEAT/2_scott_0_1_1.bvh")" "$(realpath "$BEAT/2_scott_0_1_1.wav")" "$WORK/beat2-root/"
    ln -sf "$(realpath "$BEAT2/2_scott_0_2_2.npz")" "$WORK/beat2-root/smplxflame_30/"
    ln -sf "$(realpath "$BEAT/2_scott_0_2_2.wav")" "$WORK/beat2-root/wave16k/"
    $FC prepare "$WORK/beat2-root" --out "$WORK/cache-beat" --force --quiet
    # audio and head only, as the BVH take (no face capture): the BEAT2 take's jawOpen-only face is dropped
    $PY scripts/cache_without_face.py "$WORK/cache-beat"
    $FC train --cache "$WORK/cache-beat" --speaker 2 --split all --out "$WORK/beat2-scott-demo" \
        --config configs/demo-beat2-scott.yaml --force
else
    $FC train --cache "$WORK/cache-beat" --speaker 2 --out "$WORK/beat2-scott-demo" --resume
fi
cp "$WORK/beat2-scott-demo/model.safetensors" "$STYLES/beat2-scott-demo.safetensors"
cp "$WORK/beat2-scott-demo/log.csv" "$STYLES/beat2-scott-demo.log.csv"
# figures: each take's held-out 20 % (the cache's holdout_from) and unseen speech
$PY scripts/style_report.py --checkpoint "$STYLES/beat2-scott-demo.safetensors" --cache "$WORK/cache-beat" \
    --speaker 2 --audio "$BEAT/2_scott_0_4_4.wav" --out "$WORK/beat2-scott-demo.report.json"
cp "$WORK/beat2-scott-demo.report.json" "$STYLES/beat2-scott-demo.report.json"
echo "installed into $STYLES; figures in $WORK/beat2-scott-demo.report.json (copy them into the model card)"
