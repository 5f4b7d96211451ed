#!/usr/bin/env bash
# Installs what a fresh machine lacks: system libraries (apt, when root), a virtualenv in .venv with
# the package and its test tools (EXTRAS=test,bench adds the benchmarks' comparison renderer).
# Idempotent and quick when nothing changed.
set -euo pipefail
cd "$(dirname "$0")/.."

# open3d needs libusb (imported at start) and OpenMP; libgl1 for its rendering module.
SYSTEM_PACKAGES=(libusb-1.0-0 libgomp1 libgl1)
EXTRAS=${EXTRAS:-test}
# pyrender, the rasterizer bench_render compares against, renders off-screen through OSMesa.
[[ ,$EXTRAS, == *,bench,* ]] && SYSTEM_PACKAGES+=(libosmesa6)
missing=()
for package in "${SYSTEM_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$package" 2>/dev/null | grep -q "install ok installed" || missing+=("$package")
done
if ((${#missing[@]})); then
  if [[ $(id -u) -eq 0 ]] && command -v apt-get >/dev/null; then
    echo "setup: installing system packages: ${missing[*]}"
    apt-get update -qq >/dev/null
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
  else
    echo "setup: missing system packages: ${missing[*]}; install them with: sudo apt-get install ${missing[*]}" >&2
    exit 1
  fi
fi

PYTHON=${PYTHON:-python3}
"$PYTHON" -c 'import sys; sys.exit(sys.version_info < (3, 11))' || {
  echo "setup: $PYTHON is $("$PYTHON" --version 2>&1); Python >= 3.11 is needed (set PYTHON=/path/to/python3.11)" >&2
  exit 1
}
[[ -x .venv/bin/python ]] || "$PYTHON" -m venv .venv

# Reinstall only when the dependency list changed.
stamp=.venv/.mvpd-installed
want="$(sha256sum pyproject.toml | cut -d' ' -f1) $EXTRAS"
if [[ ! -f $stamp || $(cat "$stamp") != "$want" ]]; then
  echo "setup: installing Python packages into .venv (first time: a few minutes)"
  log=.venv/pip-install.log
  if ! { .venv/bin/python -m pip install -q --upgrade pip && .venv/bin/python -m pip install -q -e ".[$EXTRAS]"; } >"$log" 2>&1; then
    grep -v "^WARNING: Location" "$log" | tail -20 >&2
    echo "setup: pip install failed (full log: $log)" >&2
    exit 1
  fi
  if [[ ,$EXTRAS, == *,bench,* ]]; then  # see the bench extra in pyproject.toml
    .venv/bin/python -m pip install -q "PyOpenGL>=3.1.5" >>"$log" 2>&1
  fi
  .venv/bin/python -c "import open3d, ray, zarr, duckdb" || { echo "setup: the install is broken (see above)" >&2; exit 1; }
  echo "$want" > "$stamp"
fi
