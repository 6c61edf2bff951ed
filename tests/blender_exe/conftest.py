"""Tier 3 fixtures: Debian's ``blender`` executable (3.4) as a subprocess, with isolated user dirs.

The package is loaded the legacy add-on way (``bl_info``): either from an isolated user scripts
directory with ``--addons hemisphere_local_pass``, or by ``--python-expr`` putting the checkout on
``sys.path`` and calling ``register()``. Every run must exit 0 with nothing on stderr.

A missing ``blender`` (or ``xvfb-run``) fails in CI (``CI`` or ``HLP_REQUIRE_BLENDER_EXE`` set) and
skips elsewhere; ``HLP_BLENDER`` names another executable.
"""

import os
import shutil
import subprocess

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PKG = "hemisphere_local_pass"
_REQUIRED = bool(os.environ.get("CI") or os.environ.get("HLP_REQUIRE_BLENDER_EXE"))

#: stderr lines Blender itself prints on a headless machine that say nothing about the add-on.
#: Kept empty unless a line is proven harmless; each entry needs a comment saying why.
STDERR_IGNORED: tuple = ()


def pytest_collection_modifyitems(config, items):
    here = os.path.dirname(os.path.abspath(__file__))
    for item in items:
        if str(item.fspath).startswith(here):
            item.add_marker(pytest.mark.blender_exe)


def _missing(what: str):
    message = f"{what} is not installed (scripts/test_tier_3_blender_exe.sh installs it with apt-get)"
    if _REQUIRED:
        pytest.fail(message + "; CI: nothing may be skipped")
    pytest.skip(message)


@pytest.fixture(scope="session")
def blender() -> str:
    """Path of the blender executable."""
    path = os.environ.get("HLP_BLENDER") or shutil.which("blender")
    if not path:
        _missing("blender")
    return path


@pytest.fixture(scope="session")
def xvfb_run() -> str:
    path = shutil.which("xvfb-run")
    if not path:
        _missing("xvfb-run")
    return path


@pytest.fixture
def blender_env(tmp_path) -> dict:
    """Environment with every Blender user directory inside ``tmp_path`` (nothing of the user's Blender)."""
    env = dict(os.environ)
    user = tmp_path / "blender-user"
    for var, sub in (
        ("BLENDER_USER_RESOURCES", ""),
        ("BLENDER_USER_CONFIG", "config"),
        ("BLENDER_USER_SCRIPTS", "scripts"),
        ("BLENDER_USER_DATAFILES", "datafiles"),
    ):
        (user / sub).mkdir(parents=True, exist_ok=True)
        env[var] = str(user / sub)
    env.pop("PYTHONPATH", None)
    env.pop("PYTHONHOME", None)
    env["PYTHONDONTWRITEBYTECODE"] = "1"  # leave no __pycache__ in the checkout
    return env


@pytest.fixture
def addon_scripts_dir(blender_env) -> str:
    """The isolated user scripts directory with ``addons/hemisphere_local_pass`` linked to the checkout."""
    scripts = blender_env["BLENDER_USER_SCRIPTS"]
    addons = os.path.join(scripts, "addons")
    os.makedirs(addons, exist_ok=True)
    os.symlink(os.path.join(ROOT, PKG), os.path.join(addons, PKG))
    return scripts


def stderr_lines(stderr: str) -> list:
    return [line for line in stderr.splitlines() if line.strip() and not line.startswith(STDERR_IGNORED or ("\0",))]


def run_blender(cmd: list, env: dict, *, timeout: float = 600, cwd: str | None = None) -> subprocess.CompletedProcess:
    """Run ``cmd`` (a blender command line) and return the completed process (text output)."""
    return subprocess.run(cmd, env=env, cwd=cwd or ROOT, capture_output=True, text=True, timeout=timeout)


def assert_clean(result: subprocess.CompletedProcess) -> None:
    """Exit code 0 and nothing on stderr; print both streams otherwise."""
    report = f"exit {result.returncode}\n--- stdout\n{result.stdout}\n--- stderr\n{result.stderr}"
    assert result.returncode == 0, report
    assert not stderr_lines(result.stderr), report


def python_expr(*lines: str) -> str:
    """A ``--python-expr`` program: put the checkout on sys.path, then ``lines``."""
    return "\n".join((f"import sys; sys.path.insert(0, {ROOT!r})",) + lines)
