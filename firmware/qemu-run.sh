#!/usr/bin/env bash
# cargo's runner for the firmware (see .cargo/config.toml): runs an ELF on
# QEMU mps2-an386 (Cortex-M4F) with -icount shift=0, so one instruction is
# one nanosecond of virtual time and SysTick counts instructions. Extra
# arguments go to QEMU (e.g. -serial options). An ELF built with the defmt
# feature logs binary defmt frames over semihosting: they are decoded with
# defmt-print (`cargo install defmt-print`) when it is installed.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
elf="$1"; shift
# The command line lives in firmware/qemu/ (the host reads the same files).
read -ra machine <"$here/qemu/mps2-an386.args"
read -ra common <"$here/qemu/common.args"
qemu=(qemu-system-arm "${machine[@]}" "${common[@]}" -kernel "$elf" "$@")
if readelf -S "$elf" 2>/dev/null | grep -q '\.defmt'; then
  if command -v defmt-print >/dev/null; then
    "${qemu[@]}" | defmt-print -e "$elf"
    exit "${PIPESTATUS[0]}"
  fi
  echo "qemu-run: $elf logs with defmt; install defmt-print to decode it (cargo install defmt-print)" >&2
fi
exec "${qemu[@]}"
