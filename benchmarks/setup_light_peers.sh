#!/usr/bin/env bash
# The peers of benchmarks/bench_light.py, each in a virtualenv of its own (never in the project's .venv):
#   Blender Cycles: bpy from PyPI (Blender as a module; it pins numpy 1.x and needs Python 3.11)
#   Mitsuba 3:      mitsuba from PyPI, variant llvm_ad_rgb; Dr.Jit's LLVM backend needs a newer LLVM
#                   than Debian 12's default: apt's libllvm19 (DRJIT_LIBLLVM_PATH points to it)
# Usage: bash benchmarks/setup_light_peers.sh [VENV_ROOT]   (default /work/venvs)
set -euo pipefail
root="${1:-/work/venvs}"
python="${PYTHON311:-python3.11}"
mkdir -p "$root"
[ -x "$root/bpy/bin/python" ] || "$python" -m venv "$root/bpy"
"$root/bpy/bin/pip" install -q bpy
[ -x "$root/mitsuba/bin/python" ] || "$python" -m venv "$root/mitsuba"
"$root/mitsuba/bin/pip" install -q mitsuba numpy
if ! ls /usr/lib/x86_64-linux-gnu/libLLVM-19.so >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ]; then apt-get update -q && apt-get install -y -q libllvm19; else
    echo "install libllvm19 with apt (as root) for Mitsuba's llvm variant"; fi
fi
echo "peers ready: $root/bpy/bin/python (Cycles), $root/mitsuba/bin/python (Mitsuba 3)"
echo "if Mitsuba cannot find LLVM: export DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so"
