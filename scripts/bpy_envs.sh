# Sourced by scripts/*.sh (after envs.sh): the bpy-module virtual environments of tier 2.
# Each pins the bpy wheel and the numpy that Blender version bundles; pytest and hypothesis as in
# TEST_TOOLS. bpy wheels exist for CPython 3.11 (Blender 4.2-5.0) and 3.13 (Blender 5.1+) only.

BPY_TEST_TOOLS=(pytest==9.2.0 hypothesis==6.170.15)

# bpy_venv VERSION : echo the venv directory for that bpy version, creating it on first use.
bpy_venv() {
    case "$1" in
        4.2) make_venv bpy-4.2 "$PY311" bpy==4.2.23 numpy==1.26.4 "${BPY_TEST_TOOLS[@]}" ;;
        4.5) make_venv bpy-4.5 "$PY311" bpy==4.5.15 numpy==1.26.4 "${BPY_TEST_TOOLS[@]}" ;;
        5.0) make_venv bpy-5.0 "$PY311" bpy==5.0.1 numpy==1.26.4 "${BPY_TEST_TOOLS[@]}" ;;
        5.2) make_venv bpy-5.2 "$PY313" bpy==5.2.3 "${BPY_TEST_TOOLS[@]}" ;;
        *) echo "bpy_venv: unknown version '$1' (4.2, 4.5, 5.0, 5.2)" >&2; return 2 ;;
    esac
}

# bpy_python VERSION : echo the venv's python (creating the venv on first use).
bpy_python() {
    local d
    d="$(bpy_venv "$1")" || return
    if [ ! -x "$d/bin/python" ] || ! "$d/bin/python" -c "import bpy" >/dev/null 2>&1; then
        echo "bpy_python: .venv/$(basename "$d") has no working bpy" >&2
        return 1
    fi
    echo "$d/bin/python"
}
