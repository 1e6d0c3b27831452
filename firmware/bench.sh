#!/usr/bin/env bash
# Onboard work of one match: matches MODEL.cmap against SCENE.cmap on the
# emulated Cortex-M4F (QEMU -icount shift=0: one instruction per virtual
# nanosecond) and prints the instructions, read from SysTick.
#   bash firmware/bench.sh MODEL.cmap SCENE.cmap
# e.g. maps from: cosem map --data ../shared/data/kitti00 --frames 0:5 --voxel 0.5 --max-range 25 -o a.cmap
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
model="$(realpath "$1")"; scene="$(realpath "$2")"
(cd "$here" && cargo build --release --locked --bin bench >&2)
work="$(mktemp -d)"; trap 'rm -rf "$work"' EXIT
cp "$model" "$work/bench-a.cmap"; cp "$scene" "$work/bench-b.cmap"
cd "$work"
read -ra machine <"$here/qemu/mps2-an386.args"
read -ra common <"$here/qemu/common.args"
qemu-system-arm "${machine[@]}" "${common[@]}" -kernel "$here/target/thumbv7em-none-eabihf/release/bench"
