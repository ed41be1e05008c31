#!/usr/bin/env bash
# Regenerate every bundled recording (all emulated by `steval synth`; see recordings/README.md).
# Builds the firmware patch's host C encoder first: the binary captures' bytes are made by the firmware's own
# encoder and TX-queue code (firmware_patch/src), so each of them is a C → Python conformance fixture.
# Run from anywhere; needs make, gcc and steval-link installed (pip install -e .). Deterministic: same bytes.
set -euo pipefail
cd "$(dirname "$0")/.."
STEVAL=${STEVAL:-steval}
make -s -C firmware_patch host
ENC=(--encoder c --c-encoder firmware_patch/host/stv_encode --force)

"$STEVAL" synth --scenario demo --duration 60 --seed 1 "${ENC[@]}" --out recordings/demo.stv
"$STEVAL" synth --scenario hover --duration 20 --join-at 18.3 --drop-rate 0.01 --seed 2 "${ENC[@]}" \
    --out recordings/midflight_drops.stv
"$STEVAL" synth --scenario freefall --duration 10 --seed 4 "${ENC[@]}" --out recordings/freefall.stv
# text mode: the plain bytes a serial terminal saves (the C host encoder takes binary frames only)
"$STEVAL" synth --scenario hand-tilts --duration 20 --seed 3 --text-mode --force --out recordings/textmode.log

# real motion from BROAD (CC BY 4.0), when the shared dataset is next to the project
BROAD=../shared/datasets/broad/07_undisturbed_fast_rotation_B.npz
if [ -f "$BROAD" ]; then
    "$STEVAL" synth --scenario "$BROAD" --join-at 24 --duration 30 --seed 5 "${ENC[@]}" --out recordings/broad_07.stv
else
    echo "make_recordings.sh: $BROAD not found; broad_07.stv left as it is" >&2
fi
ls -l recordings/
