#!/usr/bin/env bash
# Makes <repo>/.venv-cyclone-security ready for the DDS Security interoperability test
# (tests/security_interop.rs), idempotently:
#   1. system packages: Debian's Cyclone DDS 0.10 (cyclonedds-dev, cyclonedds-tools, libddsc0debian: the
#      library, its headers and IDL compiler, and the DDS Security plugins libdds_security_{auth,ac,crypto}
#      in /usr/lib/<multiarch>/libddsc0debian/); apt-get installs the missing ones when run as root;
#   2. a CYCLONEDDS_HOME for the Python binding's build, inside the venv: include and bin link to /usr's,
#      lib holds links to the system's libddsc and libcycloneddsidl (the binding loads libddsc from there);
#   3. the venv with the cyclonedds binding of the same version built from source against that library.
#      The PyPI wheels bundle a libddsc built without DDS Security; this one loads the plugins that a
#      configuration's <Security> section names;
#   4. a check that the binding loads the system's libddsc and that the plugins are there.
# A stamp file in the venv records what was built (the Python, the system Cyclone's version, this script):
# a rerun with nothing changed is a no-op, any change recreates the venv. A lock (flock on <venv>.lock)
# keeps concurrent callers from building twice.
#
# Usage: tests/python/setup_cyclone_security.sh [--system-deps]
#   --system-deps  only check/install the system packages (step 1) and exit (used by .ci/run).
# Environment: DCLOC_CYCLONE_SECURITY_VENV (venv path, default <repo>/.venv-cyclone-security),
# DCLOC_PYTHON (interpreter that creates the venv, default python3).
# Prints the venv's interpreter as its last line. Nothing here starts DDS.
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
repo=$(cd "$here/../.." && pwd)
venv=${DCLOC_CYCLONE_SECURITY_VENV:-$repo/.venv-cyclone-security}
python=${DCLOC_PYTHON:-python3}
stamp=$venv/dcloc-setup.stamp
packages=(cyclonedds-dev cyclonedds-tools libddsc0debian)
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
unset PYTHONPATH PYTHONHOME CYCLONEDDS_HOME CYCLONEDDS_URI

say() { printf '[setup_cyclone_security] %s\n' "$*" >&2; }
# shellcheck source=system_packages.sh
source "$here/system_packages.sh"
die() {
    printf '[setup_cyclone_security] ERROR: %s\n' "$*" >&2
    exit 1
}

# ---- 1. system packages -----------------------------------------------------------------------------------
installed_version() { dpkg-query -W -f '${db:Status-Status} ${Version}' "$1" 2>/dev/null | awk '$1 == "installed" { print $2 }'; }

system_deps() {
    command -v dpkg-query >/dev/null 2>&1 || die "no dpkg-query: Debian's Cyclone DDS packages are needed (${packages[*]})"
    local missing=() p
    for p in "${packages[@]}"; do
        [ -n "$(installed_version "$p")" ] || missing+=("$p")
    done
    need_venv_module missing "$python"
    install_packages "${missing[@]}"
}

if [ "${1:-}" = --system-deps ]; then
    system_deps
    exit 0
elif [ $# -gt 0 ]; then
    die "unknown argument '$1' (usage: setup_cyclone_security.sh [--system-deps])"
fi

# ---- lock, then compare the stamp -------------------------------------------------------------------------
mkdir -p "$(dirname "$venv")"
exec 9>"$venv.lock"
if ! flock -n 9; then
    say "another process is setting up $venv; waiting for it"
    flock -w 1800 9 || die "timed out after 30 min waiting for $venv.lock"
fi

system_deps
cyclone_version=$(installed_version libddsc0debian)
# The binding's version is the system library's, without the Debian revision (0.10.2-2 -> 0.10.2).
binding_version=${cyclone_version%%-*}
python_id="$(command -v "$python") $("$python" -c 'import sys; print(sys.version.split()[0])')"
env_hash=$({
    echo "$python_id"
    echo "$cyclone_version"
    sha256sum "$here/setup_cyclone_security.sh" | awk '{ print $1 }'
} | sha256sum | awk '{ print $1 }')

if [ -x "$venv/bin/python" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$env_hash" ]; then
    say "up to date: $venv"
    echo "$venv/bin/python"
    exit 0
fi

# ---- 2. CYCLONEDDS_HOME for the build -----------------------------------------------------------------------
libddsc=$(ls /usr/lib/*/libddsc.so 2>/dev/null | head -n 1)
[ -n "$libddsc" ] || die "no /usr/lib/<multiarch>/libddsc.so: is cyclonedds-dev installed?"
libdir=$(dirname "$libddsc")
plugins=$libdir/libddsc0debian
for kind in auth ac crypto; do
    [ -f "$plugins/libdds_security_$kind.so" ] || die "no $plugins/libdds_security_$kind.so (libddsc0debian)"
done

say "creating $venv with $python_id against Cyclone DDS $cyclone_version"
rm -rf "$venv"
"$python" -m venv "$venv" || die "'$python -m venv' failed"
home=$venv/cyclone-home
mkdir -p "$home/lib"
ln -s /usr/include "$home/include"
ln -s /usr/bin "$home/bin"
ln -s "$libdir"/libddsc.so* "$libdir"/libcycloneddsidl* "$home/lib/"

# ---- 3. the binding, built from source ----------------------------------------------------------------------
"$venv/bin/python" -m pip install --no-input --quiet --progress-bar off -U pip setuptools wheel ||
    die "pip install -U pip setuptools wheel failed"
# Built here, never taken from pip's wheel cache: a wheel built for another venv links that venv's home.
CYCLONEDDS_HOME=$home "$venv/bin/python" -m pip install --no-input --quiet --progress-bar off \
    --no-cache-dir --no-binary cyclonedds "cyclonedds==$binding_version" ||
    die "building cyclonedds==$binding_version against $home failed"

# ---- 4. check -----------------------------------------------------------------------------------------------
"$venv/bin/python" - "$home/lib/libddsc.so" <<'EOF' || die "the cyclonedds binding does not use the system's libddsc"
import sys

import cyclonedds.__library__ as library
from cyclonedds.domain import Domain  # loads the library

assert library.library_path == sys.argv[1], library.library_path
EOF
echo "$env_hash" >"$stamp"
say "ready: $venv (DDS Security plugins in $plugins)"
echo "$venv/bin/python"
