#!/usr/bin/env bash
# Regenerate every bundled recording (see recordings/README.md for which source made which).
# - demo.stv, freefall.stv, live_params.stv, flight.stv, preflight_*.stv: ST's real firmware (release 170120 +
#   firmware_patch) on the emulated board
#   (`steval emulate`); needs ST's sources in ../shared/st-fcu-f401 (or ST_SRC=...), arm-none-eabi-gcc and make.
# - ble_demo.stv: ST's unmodified firmware (`make stock`) on the emulated board, its BLE notifications to a central
#   (`steval emulate --ble`); the BLE tick (HAL_GetTick()>>3, u16) is started so that it wraps 30 s after power-up.
# - midflight_drops.stv, textmode.log, broad_07.stv: `steval synth`, for what it alone does (a host joining
#   mid-frame, injected queue drops, the USB-UART adapter's packet timing, a plain terminal log); their binary
#   bytes come from the firmware patch's host C encoder (firmware_patch/src), so each is a C → Python fixture.
# Run from anywhere; needs steval-link installed (pip install -e .). Deterministic: the same data bytes.
set -euo pipefail
cd "$(dirname "$0")/.."
STEVAL=${STEVAL:-steval}
ST_SRC=${ST_SRC:-../shared/st-fcu-f401}
make -s -C firmware_patch host
ENC=(--encoder c --c-encoder firmware_patch/host/stv_encode --force)

if [ -d "$ST_SRC/STM32 FW Project" ] && command -v arm-none-eabi-gcc >/dev/null; then
    ST_TMP=$(mktemp -d)
    SW_TMP=$(mktemp -d)
    trap 'rm -rf "$ST_TMP" "$SW_TMP"' EXIT
    cp -r "$ST_SRC/STM32 FW Project" "$ST_TMP/"
    (cd "$ST_TMP" && git init -q && git apply "$OLDPWD/firmware_patch/st-fcu-170120.patch")
    rm -rf firmware_patch/build/recordings  # a fresh build (its ST tree is a new temporary copy each time)
    make -s -C firmware_patch firmware ST_DIR="$ST_TMP" BUILD_DIR=build/recordings -j2
    ELF=firmware_patch/build/recordings/fw/steval-fcu-link.elf
    rm -f recordings/demo.stv recordings/freefall.stv
    "$STEVAL" emulate "$ELF" --scenario demo --duration 60 --seed 1 --no-view --out recordings/demo.stv
    "$STEVAL" emulate "$ELF" --scenario freefall --duration 10 --seed 4 --no-view --out recordings/freefall.stv
    # two-way link: KI and the correction changed live through the emulated USART1 RX (the commands are in the
    # capture's H chunks); a throttle pulse makes one change be refused
    rm -f recordings/live_params.stv
    "$STEVAL" emulate "$ELF" --scenario hand-tilts --duration 30 --seed 6 --throttle 0:0,26.1:0,26.2:300,27.2:300,27.3:0 \
        --commands recordings/live_params.commands --no-view --out recordings/live_params.stv
    # flight control (the FC frames): a flight with stick moves, the preflight check's guided moves on this build,
    # and on a build whose mixer drives motor outputs 3 and 4 swapped (the mixer renumbered to Betaflight's Quad-X
    # order; the same edit as tests/support/firmware.py swap_motor_outputs)
    rm -f recordings/flight.stv recordings/preflight_ok.stv recordings/preflight_swapped_motors.stv
    "$STEVAL" emulate "$ELF" --scenario flight --duration 27 --seed 1 --no-view --out recordings/flight.stv
    "$STEVAL" emulate "$ELF" --scenario preflight --duration 30 --seed 1 --no-view --out recordings/preflight_ok.stv
    cp -r "$ST_TMP/STM32 FW Project" "$SW_TMP/"
    sed -i -e 's/motor_pwm->motor3_pwm =/motor_pwm->motorX_pwm =/' -e 's/motor_pwm->motor4_pwm =/motor_pwm->motor3_pwm =/' \
        -e 's/motor_pwm->motorX_pwm =/motor_pwm->motor4_pwm =/' \
        "$SW_TMP/STM32 FW Project/Official release - 170120/Src/flight_control.c"
    rm -rf firmware_patch/build/recordings-swapped
    make -s -C firmware_patch firmware ST_DIR="$SW_TMP" BUILD_DIR=build/recordings-swapped -j2
    "$STEVAL" emulate firmware_patch/build/recordings-swapped/fw/steval-fcu-link.elf --scenario preflight \
        --duration 30 --seed 1 --no-view --out recordings/preflight_swapped_motors.stv
    # ST's stock build (an unpatched copy of the sources): what every BLE user's drone runs
    ST_STOCK=$(mktemp -d)
    trap 'rm -rf "$ST_TMP" "$SW_TMP" "$ST_STOCK"' EXIT
    cp -r "$ST_SRC/STM32 FW Project" "$ST_STOCK/"
    make -s -C firmware_patch stock ST_DIR="$ST_STOCK" BUILD_DIR=build/recordings -j2
    rm -f recordings/ble_demo.stv
    "$STEVAL" emulate firmware_patch/build/recordings/stock/st-fcu-stock.elf --ble --scenario demo --duration 40 \
        --seed 1 --tick-start-ms 494288 --out recordings/ble_demo.stv
else
    echo "make_recordings.sh: no $ST_SRC or no arm-none-eabi-gcc; the emulated-firmware recordings (demo, freefall," \
        "live_params, flight, preflight_*, ble_demo) left as they are" >&2
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
