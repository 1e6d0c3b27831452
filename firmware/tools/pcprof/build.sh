#!/usr/bin/env bash
# Builds the per-address instruction profiler (a QEMU 7.2 TCG plugin).
#   bash firmware/tools/pcprof/build.sh [OUTPUT.so]
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
gcc -shared -fPIC -O2 -o "${1:-$here/libpcprof.so}" "$here/pcprof.c"
