"""Tier 2 fixtures: Blender as a Python module (``bpy``), with the extension built and installed.

* The user resources (preferences, extensions, the wheels' site-packages) live in a temporary
  directory set through ``BLENDER_USER_RESOURCES`` *before* ``bpy`` is imported, so nothing of the
  developer's Blender is read or written.
* ``extension`` (session): builds the extension zip from the working tree with *this* bpy's own
  ``blender_ext.py`` (validate + build --split-platforms), installs it with
  ``bpy.ops.extensions.package_install_files`` into the ``user_default`` repository and enables it;
  returns the installed module (``bl_ext.user_default.hemisphere_local_pass``).
  ``HLP_EXTENSION_ZIP`` names a prebuilt zip to install instead.
* ``scene`` (function): a fresh empty factory-startup file (``wm.read_homefile(use_factory_startup=True,
  use_empty=True)``, which keeps the preferences, so the installed extension stays enabled).

A missing ``bpy`` fails the run in CI (``CI`` or ``HLP_REQUIRE_BPY`` set) and skips it elsewhere.
"""

import importlib.util
import os
import platform
import shutil
import sys
import tempfile

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)  # the working tree's package (its blender.job, for direct calls)

PKG_ID = "hemisphere_local_pass"
REPO = "user_default"
MODULE = f"bl_ext.{REPO}.{PKG_ID}"

_USER_DIR = tempfile.mkdtemp(prefix="hlp-blender-user-")
os.environ["BLENDER_USER_RESOURCES"] = _USER_DIR
for _var in ("BLENDER_USER_CONFIG", "BLENDER_USER_SCRIPTS", "BLENDER_USER_DATAFILES", "BLENDER_USER_EXTENSIONS"):
    os.environ.pop(_var, None)  # these would override parts of BLENDER_USER_RESOURCES

_REQUIRED = bool(os.environ.get("CI") or os.environ.get("HLP_REQUIRE_BPY"))
try:
    import bpy
except ImportError as _ex:
    if _REQUIRED:
        raise ImportError(f"tier 2 needs the bpy module (CI: nothing may be skipped): {_ex}") from _ex
    pytest.skip(f"bpy is not installed: {_ex} (run scripts/test_tier_2_bpy.sh)", allow_module_level=True)

try:
    from hypothesis import HealthCheck, settings

    settings.register_profile(
        "ci", derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow], print_blob=True
    )
    settings.register_profile("dev", deadline=None)
    settings.load_profile("ci" if os.environ.get("CI") else "dev")
except ImportError:  # hypothesis is in every tier-2 venv; this only keeps a bare bpy usable
    pass


def pytest_collection_modifyitems(config, items):
    here = os.path.dirname(os.path.abspath(__file__))
    for item in items:
        if str(item.fspath).startswith(here):
            item.add_marker(pytest.mark.bpy)


def pytest_report_header(config):
    return f"bpy {bpy.app.version_string}, Python {platform.python_version()}, user resources {_USER_DIR}"


def pytest_sessionfinish(session, exitstatus):
    shutil.rmtree(_USER_DIR, ignore_errors=True)


def blender_platform() -> str:
    """This machine as a Blender platform name (``linux-x64``, ``macos-arm64``, ``windows-x64`` ...)."""
    system = {"darwin": "macos"}.get(platform.system().lower(), platform.system().lower())
    machine = platform.machine().lower()
    machine = {"x86_64": "x64", "amd64": "x64", "aarch64": "arm64"}.get(machine, machine)
    return f"{system}-{machine}"


def load_build_script():
    """``scripts/build_extension.py`` as a module."""
    spec = importlib.util.spec_from_file_location(
        "hlp_build_extension", os.path.join(ROOT, "scripts", "build_extension.py")
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def user_dir() -> str:
    """The isolated Blender user resource directory of this test session."""
    assert bpy.utils.user_resource('EXTENSIONS').startswith(_USER_DIR), "BLENDER_USER_RESOURCES was not honoured"
    return _USER_DIR


@pytest.fixture(scope="session")
def build_script():
    return load_build_script()


@pytest.fixture(scope="session")
def built_zip(tmp_path_factory, build_script) -> str:
    """The extension zip for this platform, built from the working tree with this bpy's tool."""
    prebuilt = os.environ.get("HLP_EXTENSION_ZIP")
    if prebuilt:
        assert os.path.isfile(prebuilt), f"HLP_EXTENSION_ZIP={prebuilt} does not exist"
        return prebuilt
    out = tmp_path_factory.mktemp("dist")
    zips = build_script.build(
        bpy_python=sys.executable,
        output_dir=str(out),
        build_dir=str(tmp_path_factory.mktemp("build")),
        platforms=[blender_platform()],
    )
    assert len(zips) == 1, zips
    return zips[0]


@pytest.fixture(scope="session")
def installed_zip(built_zip, user_dir) -> str:
    """Install ``built_zip`` into the isolated ``user_default`` repository (once per session), enabled."""
    result = bpy.ops.extensions.package_install_files(filepath=built_zip, repo=REPO, enable_on_install=True)
    assert result == {'FINISHED'}, result
    assert MODULE in bpy.context.preferences.addons, [a.module for a in bpy.context.preferences.addons]
    return built_zip


def ensure_enabled():
    """Re-enable the installed extension if a test reset the preferences (``wm.read_factory_settings``)."""
    import addon_utils

    if MODULE not in bpy.context.preferences.addons:
        addon_utils.enable(MODULE, default_set=True, handle_error=_raise)
    assert MODULE in bpy.context.preferences.addons, [a.module for a in bpy.context.preferences.addons]
    return sys.modules[MODULE]


def _raise(ex):
    raise ex


@pytest.fixture
def extension(installed_zip):
    """The installed, enabled extension module (``bl_ext.user_default.hemisphere_local_pass``)."""
    return ensure_enabled()


@pytest.fixture
def scene(extension):
    """A fresh, empty factory-startup scene with the extension enabled."""
    bpy.ops.wm.read_homefile(use_factory_startup=True, use_empty=True)
    ensure_enabled()
    return bpy.context.scene
