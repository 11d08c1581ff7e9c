#!/usr/bin/env bash
# The compatibility run: every test that needs no ROS, in a Python 3.12 venv (.venv-compat)
# with Ubuntu 24.04's versions of numpy, OpenCV, scipy, numba, PyYAML and matplotlib - what
# a ROS 2 Jazzy robot has from apt - pinned by constraints-compat.txt. ROS tests are
# deselected (-m "not ros") and test files that import ROS are skipped. The simulator is
# left out: pybullet has no Python 3.12 wheel (pip would compile it, about 10 minutes on 2
# cores, on every fresh machine), and what this run checks - the core on apt's library
# versions - needs none; tests that need pybullet skip, saying so.
# Idempotent: the venv is made again only when its inputs change (stamp file).
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
VENV="$ROOT/.venv-compat"
cd "$ROOT"
say() { printf '[compat] %s\n' "$*"; }

# What the ROS-free code and tests import (test/test_package_xml.py keeps the list of
# imports; these are their PyPI names), versions from constraints-compat.txt.
PACKAGES=(numpy opencv-contrib-python-headless scipy numba pyyaml matplotlib rosbags tqdm
          pytest hypothesis)

find_python312() {
  local cand
  for cand in "${PYTHON312:-}" python3.12 "${PYENV_ROOT:-$HOME/.pyenv}"/versions/3.12*/bin/python3.12; do
    # (pyenv's shim exists but fails when 3.12 is not a selected version: try each)
    if [ -n "$cand" ] && "$cand" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 12))' 2>/dev/null; then
      command -v "$cand"; return
    fi
  done
  echo "[compat] error: no Python 3.12 found (python3.12, pyenv's versions/3.12*; or set PYTHON312)" >&2
  exit 1
}

started=$SECONDS
stamp="$VENV/.global_loc_compat"
want=$( { cat constraints-compat.txt; echo "${PACKAGES[*]}"; } | sha256sum | cut -c1-16)
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ] || [ ! -x "$VENV/bin/python" ]; then
  python=$(find_python312)
  say "making $VENV with $python and constraints-compat.txt"
  rm -rf "$VENV"
  "$python" -m venv "$VENV"
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check -c constraints-compat.txt "${PACKAGES[@]}" \
      2> >(grep -v "is ignored: it is neither a file nor a directory" >&2)
  echo "$want" > "$stamp"
else
  say "venv up to date"
fi
say "venv ready in $((SECONDS - started)) s"

# The ROS set-up of this shell (env.sh, a ROS install) must not reach Python 3.12: its
# paths hold Python 3.11 modules and libraries.
clean_env=(-u VIRTUAL_ENV -u PYTHONPATH -u AMENT_PREFIX_PATH -u COLCON_PREFIX_PATH -u CMAKE_PREFIX_PATH
           -u LD_LIBRARY_PATH -u _ROS_WHEELS_BOOTSTRAP_COMPLETE -u ROS_DISTRO -u ROS_VERSION
           -u ROS_PYTHON_VERSION -u RMW_IMPLEMENTATION)
path=$(echo "$PATH" | tr ':' '\n' | grep -vx "$ROOT/.venv/bin" | paste -sd:)
run() { env "${clean_env[@]}" PATH="$VENV/bin:$path" PYTHONPATH="$ROOT" "$VENV/bin/python" "$@"; }

run -c 'import sys, numpy, cv2, scipy, numba, yaml, matplotlib
print("[compat] Python %s, numpy %s, OpenCV %s, scipy %s, numba %s, PyYAML %s, matplotlib %s" % (
    sys.version.split()[0], numpy.__version__, cv2.__version__, scipy.__version__, numba.__version__,
    yaml.__version__, matplotlib.__version__))'
tests_started=$SECONDS
status=0
run -m pytest test -m 'not ros' -q -p no:cacheprovider "$@" || status=$?
say "tests in $((SECONDS - tests_started)) s (whole run $((SECONDS - started)) s)"
exit $status
