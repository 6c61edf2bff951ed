#!/usr/bin/env bash
# The README's test command: sets up everything it needs, then runs every test tier.
#   tier 1  pure numpy core (+ baselines), ruff; numpy 2.x and numpy 1.24
#   tier 2  Blender as a Python module (bpy 4.2 LTS, 5.2 LTS): the installed extension
#   tier 3  Debian's blender executable (3.4) headless and under Xvfb
set -euo pipefail
source "$(dirname "$0")/envs.sh"
cd "$HLP_ROOT"
status=0
run() { echo "=== $*" >&2; "$@" || status=1; }

CORE="$(core_venv)"
run "$CORE/bin/ruff" check .
run "$CORE/bin/python" -m pytest -q tests/core ${HLP_EXTRA_CORE_TESTS:-}
NP124="$(core_np124_venv)"
HYPOTHESIS_PROFILE=ci-quick run "$NP124/bin/python" -m pytest -q -p no:cacheprovider tests/core -m "not slow"

for tier in scripts/test_tier_*.sh; do
    [ -e "$tier" ] && run bash "$tier"
done

# the core once more on numpy 1.26 (what Blender 4.2-5.0 bundle), in the bpy 4.2 environment
source scripts/bpy_envs.sh
if PY42="$(bpy_python 4.2)"; then
    HYPOTHESIS_PROFILE=ci-quick run "$PY42" -m pytest -q -p no:cacheprovider tests/core -m "not slow"
else
    echo "=== no bpy 4.2 environment for the numpy 1.26 core run" >&2
    status=1
fi
exit $status
