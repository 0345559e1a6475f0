# Sourced by the setup scripts of tests/python: the system packages they need, installed with apt-get.
# The caller defines say() and die().

# Adds python3-venv to the array named $1 when the interpreter $2 lacks the venv/ensurepip modules
# (Debian's own python3 has them only with python3-venv; pyenv builds always have them).
need_venv_module() {
    local -n list=$1
    if ! "$2" -c 'import venv, ensurepip' >/dev/null 2>&1; then
        [ "$(command -v "$2")" = /usr/bin/python3 ] || die "'$2' lacks the venv/ensurepip modules"
        list+=(python3-venv)
    fi
}

# Installs the packages named as arguments with apt-get (none: nothing to do); without root or apt-get,
# stops naming them.
install_packages() {
    [ $# -eq 0 ] && return 0
    if [ "$(id -u)" -ne 0 ] || ! command -v apt-get >/dev/null 2>&1; then
        die "missing system packages: $*; install them (apt-get install -y $*) or run this as root on Debian/Ubuntu"
    fi
    say "installing system packages with apt-get: $*"
    export DEBIAN_FRONTEND=noninteractive
    # A fresh machine may have no package lists yet; a failed update is fine when the lists are there.
    apt-get update -qq || say "apt-get update failed; trying with the package lists at hand"
    apt-get install -y -qq --no-install-recommends "$@" >/dev/null || die "apt-get install $* failed"
}
