#!/usr/bin/env bash
# Regenerate the bundled recordings (see recordings/README.md for which source made which).
# - midflight_drops.stv, textmode.log, broad_07.stv: `steval synth`, for what it alone does (a host joining
#   mid-frame, injected queue drops, the USB-UART adapter's packet timing, a plain terminal log); their binary
#   bytes come from the firmware patch's host C encoder (firmware_patch/src), so each is a C -> Python fixture.
# - demo.stv, freefall.stv, live_params.stv, flight.stv, preflight_*.stv, ble_demo.stv: ST's firmware (release
#   170120, patched or stock) on the emulated board (`steval emulate`). This script never builds ST's release: give
#   it the ELFs you built yourself (STM32CubeIDE, firmware_patch/README.md), and only those recordings are remade:
#     FW_ELF=<patched release>            demo, freefall, live_params, flight, preflight_ok
#     SWAPPED_ELF=<patched release whose mixer drives motor outputs 3 and 4 swapped>   preflight_swapped_motors
#     STOCK_ELF=<unpatched release>       ble_demo (its BLE notifications; the u16 BLE tick wraps 30 s after power-up)
# Run from anywhere; needs steval-link installed (pip install -e .). Deterministic: the same data bytes.
set -euo pipefail
cd "$(dirname "$0")/.."
STEVAL=${STEVAL:-steval}
make -s -C firmware_patch host
ENC=(--encoder c --c-encoder firmware_patch/host/stv_encode --force)

if [ -n "${FW_ELF:-}" ]; then
    rm -f recordings/demo.stv recordings/freefall.stv recordings/live_params.stv recordings/flight.stv \
        recordings/preflight_ok.stv
    "$STEVAL" emulate "$FW_ELF" --scenario demo --duration 60 --seed 1 --no-view --out recordings/demo.stv
    "$STEVAL" emulate "$FW_ELF" --scenario freefall --duration 10 --seed 4 --no-view --out recordings/freefall.stv
    # two-way link: KI and the correction changed live through the emulated USART1 RX (the commands are in the
    # capture's H chunks); a throttle pulse makes one change be refused
    "$STEVAL" emulate "$FW_ELF" --scenario hand-tilts --duration 30 --seed 6 \
        --throttle-schedule 0:0,26.1:0,26.2:300,27.2:300,27.3:0 --commands recordings/live_params.commands --no-view \
        --out recordings/live_params.stv
    # flight control (the FC frames): a flight with stick moves, the preflight check's guided moves
    "$STEVAL" emulate "$FW_ELF" --scenario flight --duration 27 --seed 1 --no-view --out recordings/flight.stv
    "$STEVAL" emulate "$FW_ELF" --scenario preflight --duration 30 --seed 1 --no-view --out recordings/preflight_ok.stv
else
    echo "make_recordings.sh: FW_ELF not set; demo, freefall, live_params, flight, preflight_ok left as they are" >&2
fi
if [ -n "${SWAPPED_ELF:-}" ]; then
    rm -f recordings/preflight_swapped_motors.stv
    "$STEVAL" emulate "$SWAPPED_ELF" --scenario preflight --duration 30 --seed 1 --no-view \
        --out recordings/preflight_swapped_motors.stv
fi
if [ -n "${STOCK_ELF:-}" ]; then
    rm -f recordings/ble_demo.stv
    "$STEVAL" emulate "$STOCK_ELF" --ble --scenario demo --duration 40 --seed 1 --tick-start-ms 494288 \
        --out recordings/ble_demo.stv
fi

"$STEVAL" synth --scenario hover --duration 20 --join-at 18.31 --drop-rate 0.01 --seed 2 "${ENC[@]}" \
    --out recordings/midflight_drops.stv
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
