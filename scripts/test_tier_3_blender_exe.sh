#!/usr/bin/env bash
# Tier 3: Debian's blender executable (3.4) as a subprocess, headless (-b) and under Xvfb.
# Installs what it needs with apt-get (non-interactive, only what is missing), then runs
# tests/blender_exe with the core venv's pytest. Any failure exits non-zero; nothing is skipped.
set -uo pipefail
source "$(dirname "$0")/envs.sh"
cd "$HLP_ROOT"
t_all=$(date +%s)

# blender: the executable; python3-numpy: Debian's Blender uses the system Python 3.11 and its numpy
# (1.24, which the core supports) but does not depend on it; xvfb + xauth: xvfb-run for the UI test;
# libgl1-mesa-dri: software OpenGL for the UI; xdotool: real input events (Esc, clicks) in the UI tests.
APT_PACKAGES=(blender python3-numpy xvfb xauth libgl1-mesa-dri xdotool)
missing=()
for p in "${APT_PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
    echo "[setup] apt-get install ${missing[*]}" >&2
    SUDO=""
    [ "$(id -u)" -ne 0 ] && SUDO="sudo -n"
    export DEBIAN_FRONTEND=noninteractive
    $SUDO apt-get update -q >&2 || { echo "tier 3: FAILED: apt-get update" >&2; exit 1; }
    $SUDO apt-get install -y -q --no-install-recommends "${missing[@]}" >&2 \
        || { echo "tier 3: FAILED: apt-get install ${missing[*]}" >&2; exit 1; }
fi
echo "[time] tier 3 setup: $(( $(date +%s) - t_all )) s" >&2

CORE="$(core_venv)"
t0=$(date +%s)
echo "=== tier 3: $(blender --version 2>/dev/null | head -1)" >&2
HLP_REQUIRE_BLENDER_EXE=1 "$CORE/bin/python" -m pytest -q -p no:cacheprovider tests/blender_exe
status=$?
echo "[time] tier 3 tests: $(( $(date +%s) - t0 )) s, total $(( $(date +%s) - t_all )) s" >&2
exit $status
