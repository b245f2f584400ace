#!/usr/bin/env bash
# Idempotent set-up of aeropend on a plain Debian/Ubuntu machine:
#   1. Debian packages listed in scripts/apt-packages.txt (only when one is missing: apt-get update, then install);
#   2. a virtual environment in .venv with every Python dependency: the runtime ones (requirements.txt, ROS 2 Jazzy
#      wheels included) and those of the tests, benchmarks and lint (requirements-dev.txt, which includes the first);
#   3. the project itself, editable, so `.venv/bin/aeropend` runs the current tree;
#   4. numba's on-disk cache of the numerical kernels, warmed (scripts/warm_numba_cache.py).
# Re-running it changes nothing when nothing changed (a hash of the dependency files is kept in .venv).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"

mapfile -t debs < <(sed -e 's/#.*//' -e '/^\s*$/d' scripts/apt-packages.txt)
missing=()
for pkg in "${debs[@]}"; do
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
if ((${#missing[@]})); then
  sudo=""; [ "$(id -u)" = 0 ] || sudo=sudo
  echo "setup: installing Debian packages: ${missing[*]}"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

python=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv with $($python --version)"
  "$python" -m venv .venv
fi
want=$(cat requirements.txt requirements-dev.txt setup.py setup.cfg package.xml | sha256sum | cut -d' ' -f1)
have=$(cat .venv/.aeropend-deps 2>/dev/null || true)
if [ "$want" != "$have" ]; then
  echo "setup: installing Python dependencies into .venv (first time takes a few minutes)"
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -r requirements-dev.txt
  .venv/bin/python -m pip install -q --no-deps -e .
  echo "$want" > .venv/.aeropend-deps
fi
# numba kernels compiled ahead (not in the first identification window); seconds when the cache is warm
.venv/bin/python scripts/warm_numba_cache.py
echo "setup: ready (.venv/bin/aeropend)"
