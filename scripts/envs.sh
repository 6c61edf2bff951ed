# Sourced by scripts/*.sh: creates the project's virtual environments on first use.
# Every environment lives under .venv/ in the checkout, so a fresh clone sets itself up.
# Versions are pinned: numpy 1.26 is what Blender 4.2-5.0 bundle, 2.x what 5.1+ bundle,
# 1.24 what Debian's Blender 3.4 uses; the core must run on all of them.

HLP_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
HLP_VENVS="$HLP_ROOT/.venv"
# A pyenv shim named python3.13 may exist without 3.13 being selected: use a Python that runs.
_hlp_working_python() {
    local candidate
    for candidate in "$@"; do
        if [ -n "$candidate" ] && "$candidate" -c "import sys" >/dev/null 2>&1; then
            echo "$candidate"
            return 0
        fi
    done
    echo "no working Python among: $*" >&2
    return 1
}
PY311="$(_hlp_working_python "${HLP_PY311:-}" "$HOME"/.pyenv/versions/3.11*/bin/python3.11 \
    "$(command -v python3.11)" || true)"
PY313="$(_hlp_working_python "${HLP_PY313:-}" "$HOME"/.pyenv/versions/3.13*/bin/python3.13 \
    "$(command -v python3.13)" || true)"

TEST_TOOLS=(pytest==9.2.0 hypothesis==6.170.15 ruff==0.17.6)

# make_venv NAME PYTHON PACKAGES... : (re)use .venv/NAME, installing PACKAGES once (stamp file).
make_venv() {
    local name="$1" python="$2"; shift 2
    local dir="$HLP_VENVS/$name" stamp
    stamp="$(printf '%s\n' "$@" | sha1sum | cut -c1-12)"
    if [ ! -f "$dir/.stamp-$stamp" ]; then
        echo "[setup] creating .venv/$name ($*)" >&2
        rm -rf "$dir"
        [ -n "$python" ] || { echo "make_venv $name: no Python interpreter" >&2; return 1; }
        "$python" -m venv "$dir" || return 1
        "$dir/bin/python" -m pip install -q --disable-pip-version-check --upgrade pip >&2 || return 1
        "$dir/bin/python" -m pip install -q --disable-pip-version-check "$@" >&2 || return 1
        touch "$dir/.stamp-$stamp"
    fi
    echo "$dir"
}

core_venv() { make_venv core "$PY311" numpy==2.4.6 "${TEST_TOOLS[@]}" matplotlib==3.11.2 openexr==3.5.3 dask==2026.8.0 distributed==2026.8.0; }
core_np124_venv() { make_venv core-np124 "$PY311" numpy==1.24.4 pytest==9.2.0 hypothesis==6.170.15; }
