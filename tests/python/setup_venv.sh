#!/usr/bin/env bash
# Makes <repo>/.venv ready for the ROS 2 tests, idempotently:
#   1. system tools: cmake and a C/C++ compiler (apt-get installs the missing ones when run as root),
#      Python's venv module;
#   2. the venv with the pinned wheels of tests/python/requirements.txt (real ROS 2 Jazzy rclpy on Fast DDS,
#      message packages, cyclonedds-python, rosbags, and the build tools for step 3);
#   3. the wheels' exported CMake paths fixed (they name the wheel build machine's Python and numpy headers);
#   4. the dc_loc interface package (msg/) built with cmake and installed into the venv;
#   5. a check that `from dc_loc.msg import LoopClosure` works and its type support loads.
# A stamp file in the venv records what was built (hashes of the Python, requirements.txt, this script and
# msg/): a rerun with nothing changed is a no-op, a change to msg/ rebuilds only the interface package, any
# other change recreates the venv. A lock (flock on <venv>.lock) keeps concurrent callers from building
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
build_dir=$venv/build/dc_loc_msg
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
# A sourced ROS installation must not leak into the venv's build or imports.
unset PYTHONPATH PYTHONHOME AMENT_PREFIX_PATH CMAKE_PREFIX_PATH COLCON_PREFIX_PATH

say() { printf '[setup_venv] %s\n' "$*"; }
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
    command -v "$python" >/dev/null 2>&1 || die "no '$python' on PATH (set DCLOC_PYTHON to a CPython 3.11)"
    # Debian's own python3 has venv/ensurepip only with python3-venv (pyenv builds always have them).
    if ! "$python" -c 'import venv, ensurepip' >/dev/null 2>&1; then
        [ "$(command -v "$python")" = /usr/bin/python3 ] || die "'$python' lacks the venv/ensurepip modules"
        missing+=(python3-venv)
    fi
    [ ${#missing[@]} -eq 0 ] && return 0
    if [ "$(id -u)" -ne 0 ] || ! command -v apt-get >/dev/null 2>&1; then
        die "missing system packages: ${missing[*]}; install them (apt-get install -y ${missing[*]}) or run this as root on Debian/Ubuntu"
    fi
    say "installing system packages with apt-get: ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    # A fresh machine may have no package lists yet; a failed update is fine when the lists are there.
    apt-get update -qq || say "apt-get update failed; trying with the package lists at hand"
    apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null ||
        die "apt-get install ${missing[*]} failed"
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
# The interface package: every file under msg/ (names and contents).
msg_hash=$(cd "$repo" && find msg -type f -print0 | LC_ALL=C sort -z | xargs -0 sha256sum | sha256sum | awk '{ print $1 }')

stamp_get() { [ -f "$stamp" ] && awk -v k="$1" '$1 == k { print $2 }' "$stamp" || true; }
stamp_write() { # atomically: key value [key value]
    printf '%s %s\n' "$@" >"$stamp.tmp" && mv "$stamp.tmp" "$stamp"
}

if [ -x "$venv/bin/python" ] && [ "$(stamp_get env)" = "$env_hash" ] && [ "$(stamp_get msg)" = "$msg_hash" ]; then
    say "up to date: $venv"
    exit 0
fi

system_deps

# ---- 2. venv and wheels -----------------------------------------------------------------------------------
if [ -x "$venv/bin/python" ] && [ "$(stamp_get env)" = "$env_hash" ]; then
    say "venv current; rebuilding the interface package only (msg/ changed or its build was cut short)"
else
    say "creating $venv with $python_id"
    rm -f "$stamp"
    "$python" -m venv --clear "$venv" || die "'$python -m venv' failed"
    stage_done "venv created"
    "$venv/bin/python" -m pip install --no-input --quiet --progress-bar off -r "$requirements" ||
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

# ---- 4. build and install the interface package -----------------------------------------------------------
rm -rf "$build_dir"
cmake_env=(env "AMENT_PREFIX_PATH=$venv" "CMAKE_PREFIX_PATH=$venv" "PATH=$venv/bin:$PATH")
build_log=$venv/build/dc_loc_msg.log
mkdir -p "$venv/build"
{
    "${cmake_env[@]}" cmake -S "$repo/msg" -B "$build_dir" \
        -DCMAKE_INSTALL_PREFIX="$venv" \
        -DPython3_EXECUTABLE="$venv/bin/python" \
        -DBUILD_TESTING=OFF &&
        "${cmake_env[@]}" cmake --build "$build_dir" --parallel "$(nproc)" &&
        "${cmake_env[@]}" cmake --install "$build_dir"
} >"$build_log" 2>&1 || {
    tail -n 40 "$build_log" >&2
    die "building msg/ failed (full log: $build_log)"
}
stage_done "msg/ built and installed (cmake)"

# ---- 5. check ---------------------------------------------------------------------------------------------
# Loads the generated Python module and its C type support; serializing goes through rmw_fastrtps's CDR
# code without creating any DDS participant.
"$venv/bin/python" - <<'EOF' || die "the installed dc_loc interface package does not import"
from dc_loc.msg import LoopClosure
from rclpy.serialization import deserialize_message, serialize_message

msg = LoopClosure()
msg.query_id = 7
assert deserialize_message(serialize_message(msg), LoopClosure).query_id == 7
EOF
stamp_write env "$env_hash" msg "$msg_hash"
stage_done "import check"
say "$(awk -v a="$t_start" -v b="$EPOCHREALTIME" 'BEGIN { printf "ready in %.1f s", b - a }'): $venv"
