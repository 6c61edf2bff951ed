#!/usr/bin/env bash
# Regenerate the UI screenshots in docs/ (docs/ui_*.png, shown in README.md and docs/blender.md):
# Debian's blender 3.4 in a real window under Xvfb, driven by scripts/ui_session.py with xdotool input
# (the same session tests/blender_exe/test_ui.py checks). Needs: apt-get install blender xvfb xauth
# xdotool libgl1-mesa-dri (scripts/test_tier_3_blender_exe.sh installs them). Takes ~2 minutes.
#   HLP_RESOLUTION (default 48): size of the modal job's image (larger: a longer run to catch mid-way).
set -euo pipefail
source "$(dirname "$0")/envs.sh"
cd "$HLP_ROOT"
for tool in blender xvfb-run xdotool; do
    command -v "$tool" >/dev/null || { echo "ui_screenshots: $tool is missing (apt-get install blender xvfb xauth xdotool libgl1-mesa-dri)" >&2; exit 1; }
done
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
export PYTHONDONTWRITEBYTECODE=1
blender -b --factory-startup --python-exit-code 1 --python sample_scenes/cornell_box.py -- \
    "$tmp/cornell_box.blend" --subdivisions 4 --resolution 64 >/dev/null
mkdir -p "$tmp/config" "$tmp/scripts"
LIBGL_ALWAYS_SOFTWARE=1 BLENDER_USER_CONFIG="$tmp/config" BLENDER_USER_SCRIPTS="$tmp/scripts" \
    xvfb-run -a -s "-screen 0 1280x800x24" blender --factory-startup "$tmp/cornell_box.blend" \
    --window-geometry 0 0 1280 800 --python scripts/ui_session.py -- \
    --out "$tmp/shots" --result "$tmp/ui.json" --resolution "${HLP_RESOLUTION:-48}" >"$tmp/log.txt" 2>&1 || true
python3 - "$tmp/ui.json" <<'PYEOF' || { cat "$tmp/log.txt" >&2; exit 1; }
import json, sys
info = json.load(open(sys.argv[1]))
if not info.get("ok"):
    sys.exit("ui_screenshots: the session failed: " + str(info.get("error")))
m, i = info["modal"], info["inspector"]
print(f"modal job: {m['summary']}; screenshot at {100 * m['first']['fraction']:.0f} %")
print(f"inspector at {i['point']}: sum F = {i['form_factor_sum']!r}, {i['rows']} polygons, list == core: {i['rows_equal_core']}")
PYEOF
for name in ui_engine_panels ui_other_engine ui_progress ui_result ui_inspector ui_inspector_form_factor ui_baked; do
    cp "$tmp/shots/$name.png" "docs/$name.png"
done
echo "ui_screenshots: wrote docs/ui_*.png"
