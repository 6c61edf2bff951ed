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
run "$NP124/bin/python" -m pytest -q -p no:cacheprovider tests/core -m "not slow"

for tier in scripts/test_tier_*.sh; do
    [ -e "$tier" ] && run bash "$tier"
done
exit $status
