#!/usr/bin/env bash
# Makes <repo>/.venv ready for the ROS 2 tests, idempotently:
#   1. system tools: cmake and a C/C++ compiler, libusb-1.0 for open3d (apt-get installs the missing ones
#      when run as root), Python's venv module;
#   2. the venv with the pinned wheels of tests/python/requirements.txt (real ROS 2 Jazzy rclpy on Fast DDS,
#      message packages, cyclonedds-python, rosbags, and the build tools for step 3);
#   3. the wheels' exported CMake paths fixed (they name the wheel build machine's Python and numpy headers);
#   4. the interface packages built with cmake and installed into the venv, each of INTERFACE_PACKAGES in
#      turn: dc_loc's own (msg/) and the ones the tests read besides (tests/python/interfaces/*:
#      pose_graph_tools_msgs, tf2_msgs, radar_msgs);
#   5. a check that each package's messages import and their type support loads.
# A stamp file in the venv records what was built (hashes of the Python, requirements.txt, this script and
# every file of the interface packages): a rerun with nothing changed is a no-op, a change to an interface
# package rebuilds only the interface packages, any other change recreates the venv. A lock (flock on <venv>.lock) keeps concurrent callers from building
# twice: the second one waits and then finds the stamp current.
#
# Usage: tests/python/setup_venv.sh [--system-deps]
#   --system-deps  only check/install the system tools (step 1) and exit (used by .ci/run).
# Environment: DCLOC_VENV (venv path, default <repo>/.venv), DCLOC_PYTHON (interpreter that creates the
# venv, default python3; the pins are for CPython 3.11).
# Nothing here starts DDS; ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST is still exported, to be sure.
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
repo=$(cd "$here/../.." && pwd)
venv=${DCLOC_VENV:-$repo/.venv}
python=${DCLOC_PYTHON:-python3}
requirements=$here/requirements.txt
stamp=$venv/dcloc-setup.stamp
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
# A sourced ROS installation must not leak into the venv's build or imports.
unset PYTHONPATH PYTHONHOME AMENT_PREFIX_PATH CMAKE_PREFIX_PATH COLCON_PREFIX_PATH

say() { printf '[setup_venv] %s\n' "$*"; }
# shellcheck source=system_packages.sh
source "$here/system_packages.sh"
die() {
    printf '[setup_venv] ERROR: %s\n' "$*" >&2
    exit 1
}

t_start=$EPOCHREALTIME
t_stage=$t_start
# Prints the wall time of the stage that just finished.
stage_done() {
    local now=$EPOCHREALTIME
    say "$(awk -v a="$t_stage" -v b="$now" -v n="$1" 'BEGIN { printf "%-34s %7.1f s", n, b - a }')"
    t_stage=$now
}

# ---- 1. system tools --------------------------------------------------------------------------------------
system_deps() {
    local missing=()
    command -v cmake >/dev/null 2>&1 || missing+=(cmake)
    command -v cc >/dev/null 2>&1 || missing+=(gcc)
    command -v c++ >/dev/null 2>&1 || missing+=(g++)
    command -v make >/dev/null 2>&1 || missing+=(make)
    # perl builds the OpenSSL of DDS Security (openssl-src); the openssl CLI makes the security tests'
    # keystore (launch_scripts/make_keystore.sh).
    command -v perl >/dev/null 2>&1 || missing+=(perl)
    command -v openssl >/dev/null 2>&1 || missing+=(openssl)
    # open3d-cpu (examples/peers.py) links the system's libusb-1.0 when it imports.
    PATH=$PATH:/sbin:/usr/sbin ldconfig -p 2>/dev/null | grep -q 'libusb-1\.0\.so\.0' || missing+=(libusb-1.0-0)
    command -v "$python" >/dev/null 2>&1 || die "no '$python' on PATH (set DCLOC_PYTHON to a CPython 3.11)"
    need_venv_module missing "$python"
    [ ${#missing[@]} -eq 0 ] && return 0
    install_packages "${missing[@]}"
    stage_done "system packages (apt-get)"
}

if [ "${1:-}" = --system-deps ]; then
    system_deps
    exit 0
elif [ $# -gt 0 ]; then
    die "unknown argument '$1' (usage: setup_venv.sh [--system-deps])"
fi

# ---- lock, then compare the stamp -------------------------------------------------------------------------
mkdir -p "$(dirname "$venv")"
exec 9>"$venv.lock"
if ! flock -n 9; then
    say "another process is setting up $venv; waiting for it"
    flock -w 1800 9 || die "timed out after 30 min waiting for $venv.lock"
fi

hash_files() { sha256sum "$@" | awk '{ print $1 }' | sha256sum | awk '{ print $1 }'; }
# The environment: interpreter (path and version), pinned wheels, this script (its fix-ups and build steps).
python_id=$(command -v "$python" 2>/dev/null || echo "$python")
python_id="$python_id $("$python" -c 'import sys; print(sys.version.split()[0])' 2>/dev/null || echo none)"
env_hash=$({
    echo "$python_id"
    hash_files "$requirements" "$here/setup_venv.sh"
} | sha256sum | awk '{ print $1 }')
# The interface packages (folders with a package.xml, relative to the repository), built in this order,
# and one message of each that the check of step 5 imports.
INTERFACE_PACKAGES=(msg tests/python/interfaces/pose_graph_tools_msgs tests/python/interfaces/tf2_msgs
    tests/python/interfaces/radar_msgs)
INTERFACE_CHECKS=("dc_loc.msg:LoopClosure" "pose_graph_tools_msgs.msg:PoseGraph" "tf2_msgs.msg:TFMessage"
    "radar_msgs.msg:RadarScan")
# Every file of every interface package (names and contents).
interfaces_hash=$(cd "$repo" && find "${INTERFACE_PACKAGES[@]}" -type f -print0 | LC_ALL=C sort -z |
    xargs -0 sha256sum | sha256sum | awk '{ print $1 }')

stamp_get() { [ -f "$stamp" ] && awk -v k="$1" '$1 == k { print $2 }' "$stamp" || true; }
stamp_write() { # atomically: key value [key value]
    printf '%s %s\n' "$@" >"$stamp.tmp" && mv "$stamp.tmp" "$stamp"
}

if [ -x "$venv/bin/python" ] && [ "$(stamp_get env)" = "$env_hash" ] &&
    [ "$(stamp_get interfaces)" = "$interfaces_hash" ]; then
    say "up to date: $venv"
    exit 0
fi

system_deps

# ---- 2. venv and wheels -----------------------------------------------------------------------------------
if [ -x "$venv/bin/python" ] && [ "$(stamp_get env)" = "$env_hash" ]; then
    say "venv current; rebuilding the interface packages only (one changed or their build was cut short)"
else
    say "creating $venv with $python_id"
    rm -f "$stamp"
    "$python" -m venv --clear "$venv" || die "'$python -m venv' failed"
    stage_done "venv created"
    # No wheel cache: the wheels (open3d, gtsam, the ROS 2 ones) would take their size on the disk twice.
    "$venv/bin/python" -m pip install --no-input --quiet --progress-bar off --no-cache-dir -r "$requirements" ||
        die "pip install -r $requirements failed"
    stage_done "pip install (pinned wheels)"

    # ---- 3. fix the wheels' exported CMake paths --------------------------------------------------------
    # Each *_msgs wheel exports its Python-generator target with include dirs of the machine that built it
    # (/opt/python/cp311-cp311/include/python3.11 and that Python's numpy/_core/include).
    py_include=$("$venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
    np_include=$("$venv/bin/python" -c 'import numpy; print(numpy.get_include())')
    [ -f "$py_include/Python.h" ] || die "no Python.h in $py_include: the interpreter lacks its C headers"
    shopt -s nullglob
    exports=("$venv"/share/*/cmake/export_*__rosidl_generator_pyExport.cmake)
    shopt -u nullglob
    [ ${#exports[@]} -gt 0 ] || die "no export_*__rosidl_generator_pyExport.cmake in $venv/share: wheel layout changed?"
    sed -i -E \
        -e "s#/opt/python/[^;\"]*/numpy/_core/include#${np_include}#g" \
        -e "s#/opt/python/[^;\"]*/include/python3\\.[0-9]+#${py_include}#g" \
        "${exports[@]}"
    if grep -l '/opt/python' "${exports[@]}" >/dev/null; then
        die "paths of the wheels' build machine left in: $(grep -l '/opt/python' "${exports[@]}" | head -3)"
    fi
    stamp_write env "$env_hash"
    stage_done "CMake export paths fixed (${#exports[@]})"
fi

# ---- 4. build and install the interface packages ----------------------------------------------------------
cmake_env=(env "AMENT_PREFIX_PATH=$venv" "CMAKE_PREFIX_PATH=$venv" "PATH=$venv/bin:$PATH")
mkdir -p "$venv/build"
for package in "${INTERFACE_PACKAGES[@]}"; do
    source_dir=$repo/$package
    name=$(sed -n 's:.*<name>\(.*\)</name>.*:\1:p' "$source_dir/package.xml" | head -n 1)
    [ -n "$name" ] || die "no <name> in $source_dir/package.xml"
    build_dir=$venv/build/$name
    build_log=$venv/build/$name.log
    rm -rf "$build_dir"
    {
        "${cmake_env[@]}" cmake -S "$source_dir" -B "$build_dir" \
            -DCMAKE_INSTALL_PREFIX="$venv" \
            -DPython3_EXECUTABLE="$venv/bin/python" \
            -DBUILD_TESTING=OFF -DDC_LOC_BUILD_NODE=OFF &&
            "${cmake_env[@]}" cmake --build "$build_dir" --parallel "$(nproc)" &&
            "${cmake_env[@]}" cmake --install "$build_dir"
    } >"$build_log" 2>&1 || {
        tail -n 40 "$build_log" >&2
        die "building $package ($name) failed (full log: $build_log)"
    }
    stage_done "$name built and installed (cmake)"
done

# ---- 5. check ---------------------------------------------------------------------------------------------
# Loads each package's generated Python module and its C type support; serializing goes through
# rmw_fastrtps's CDR code without creating any DDS participant.
"$venv/bin/python" - "${INTERFACE_CHECKS[@]}" <<'EOF' || die "an installed interface package does not import"
import importlib
import sys

from rclpy.serialization import deserialize_message, serialize_message

for check in sys.argv[1:]:
    module, name = check.split(":")
    cls = getattr(importlib.import_module(module), name)
    msg = cls()
    assert deserialize_message(serialize_message(msg), cls) == msg, check
EOF
stamp_write env "$env_hash" interfaces "$interfaces_hash"
stage_done "import check"
say "$(awk -v a="$t_start" -v b="$EPOCHREALTIME" 'BEGIN { printf "ready in %.1f s", b - a }'): $venv"
