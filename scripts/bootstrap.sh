#!/usr/bin/env bash
# Set up everything the workbench needs on a fresh Debian/Ubuntu machine with Python >= 3.11:
#   1. the LLVM 19 shared library that Dr.Jit's LLVM backend loads (Debian package libllvm19),
#   2. Debian's chromium (the browser check of the HTML reports; WORKBENCH_NO_CHROMIUM=1 leaves it out),
#   3. a virtual environment in .venv with the project and its test tools.
# Idempotent: re-running it only installs what is missing.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
PYTHON="${PYTHON:-python3}"

have_llvm19() {
    local pattern
    for pattern in '/usr/lib/*/libLLVM-19*.so*' '/usr/lib/*/libLLVM.so.19*' '/usr/lib/llvm-19/lib/libLLVM*.so*'; do
        compgen -G "$pattern" >/dev/null && return 0
    done
    return 1
}

# apt_install PACKAGE WHY: Debian's package, as root or through sudo
apt_install() {
    local SUDO=""
    [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    echo "[bootstrap] installing $1 ($2)"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "$1" >/dev/null
}

if ! have_llvm19; then
    if command -v apt-get >/dev/null 2>&1; then
        apt_install libllvm19 "needed by Dr.Jit's LLVM backend"
    else
        echo "[bootstrap] WARNING: no apt-get; install LLVM 19's shared library (libLLVM-19.so) yourself" >&2
    fi
fi

# Debian's Chromium: the browser check reads every HTML report as its reader does (workbench.reporting.browser_check);
# without it those tests are skipped. WORKBENCH_NO_CHROMIUM=1 leaves it out.
if [ "${WORKBENCH_NO_CHROMIUM:-0}" != "1" ] && ! command -v chromium >/dev/null 2>&1; then
    if command -v apt-get >/dev/null 2>&1 && { [ "$(id -u)" -eq 0 ] || command -v sudo >/dev/null 2>&1; }; then
        apt_install chromium "Debian's Chromium: the browser check of the HTML reports"
    else
        echo "[bootstrap] note: no chromium and no apt-get: the browser check of the reports is skipped" >&2
    fi
fi

if [ ! -x .venv/bin/python ]; then
    echo "[bootstrap] creating .venv with $($PYTHON --version)"
    "$PYTHON" -m venv .venv
fi
# Skip pip when the installed project is already current (saves ~20 s on repeated runs).
stamp=".venv/.installed-$(sha1sum pyproject.toml | cut -c1-12)"
if [ ! -f "$stamp" ]; then
    echo "[bootstrap] installing the project and its dependencies into .venv"
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -e ".[test]"
    rm -f .venv/.installed-* && touch "$stamp"
fi
echo "[bootstrap] ready: $(.venv/bin/python -c 'from importlib.metadata import version as v; print("mitsuba", v("mitsuba"), "drjit", v("drjit"))')"
