"""Build the Blender extension archives of hemisphere_local_pass into dist/.

Steps (as BradyAJohnston/MolecularNodes' build.py does, with Blender's own tool doing the packaging):

1. stage ``hemisphere_local_pass/`` with ``blender_manifest.toml`` at its root into
   ``build/hemisphere_local_pass/`` (the extension archive's root is the package itself);
2. download the pinned ``openexr`` wheels for Blender's Pythons (3.11 for Blender 4.2-5.0, 3.13 for
   5.1+) and every platform of the manifest into the staged ``wheels/`` (cached in
   ``build/wheels-cache/``; numpy is never bundled: Blender ships it);
3. list them in the staged manifest's ``wheels``;
4. run Blender's ``extension validate`` and ``extension build --split-platforms`` with the
   ``blender_ext.py`` that ships inside the bpy wheel
   (``bpy/<ver>/scripts/addons_core/bl_pkg/cli/blender_ext.py``), using that venv's Python.

Usage::

    python scripts/build_extension.py [--bpy-python .venv/bpy-4.2/bin/python] [--offline]

Exit code 0 on success; every failure prints one line naming the step and exits non-zero.
"""

from __future__ import annotations

import argparse
import glob
import os
import re
import shutil
import subprocess
import sys

import tomllib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PACKAGE = "hemisphere_local_pass"
MANIFEST = "blender_manifest.toml"

# Pinned: the same version the core venv tests the EXR reader with (scripts/envs.sh).
OPENEXR_REQUIREMENT = "openexr==3.5.3"
PYTHON_VERSIONS = ("3.11", "3.13")

# Blender platform -> pip --platform tags, best first (pip picks the first wheel that exists).
# Blender 4.2+ is built against glibc 2.28 on Linux and macOS 11 (arm64) / 10.15 (x64).
PLATFORM_TAGS = {
    "linux-x64": ["manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64"],
    "linux-arm64": ["manylinux_2_28_aarch64", "manylinux_2_17_aarch64", "manylinux2014_aarch64"],
    "macos-arm64": [f"macosx_{v}_arm64" for v in ("11_0", "12_0")] + ["macosx_11_0_universal2"],
    "macos-x64": [f"macosx_{v}_x86_64" for v in ("10_15", "10_13", "10_9", "11_0")] + ["macosx_10_9_universal2"],
    "windows-x64": ["win_amd64"],
}


class BuildError(RuntimeError):
    """A build step failed; the message names the step."""


def blender_ext_tool(bpy_python: str) -> str:
    """Path of ``blender_ext.py`` inside the bpy wheel installed for ``bpy_python``."""
    out = subprocess.run(
        [bpy_python, "-c", "import importlib.util as u; print(u.find_spec('bpy').submodule_search_locations[0])"],
        capture_output=True,
        text=True,
    )
    if out.returncode != 0:
        raise BuildError(f"no bpy module for {bpy_python}: {out.stderr.strip().splitlines()[-1:]}")
    bpy_dir = out.stdout.strip()
    found = sorted(glob.glob(os.path.join(bpy_dir, "*", "scripts", "addons_core", "bl_pkg", "cli", "blender_ext.py")))
    if not found:
        raise BuildError(f"blender_ext.py not found under {bpy_dir}")
    return found[-1]


def default_bpy_python() -> str:
    """The first bpy venv of the checkout (oldest Blender first: its validator is the strictest baseline)."""
    for version in ("4.2", "4.5", "5.0", "5.2"):
        candidate = os.path.join(ROOT, ".venv", f"bpy-{version}", "bin", "python")
        if os.path.exists(candidate):
            return candidate
    raise BuildError("no .venv/bpy-*/bin/python: run scripts/test_tier_2_bpy.sh or pass --bpy-python")


def stage(build_dir: str) -> str:
    """Copy the package and the manifest into ``build_dir/hemisphere_local_pass``; return that directory."""
    staged = os.path.join(build_dir, PACKAGE)
    shutil.rmtree(staged, ignore_errors=True)
    shutil.copytree(
        os.path.join(ROOT, PACKAGE),
        staged,
        ignore=shutil.ignore_patterns("__pycache__", "*.pyc", ".*"),
    )
    shutil.copy2(os.path.join(ROOT, MANIFEST), os.path.join(staged, MANIFEST))
    return staged


def wheel_platform_tags(path: str) -> list[str]:
    """Platform tags of a wheel file name (``...-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl``)."""
    return os.path.basename(path)[: -len(".whl")].split("-")[-1].split(".")


def download_wheels(cache_dir: str, platforms: list[str], offline: bool) -> list[str]:
    """Download (or reuse from ``cache_dir``) one openexr wheel per (Python, platform); return their paths."""
    os.makedirs(cache_dir, exist_ok=True)
    name = OPENEXR_REQUIREMENT.split("==")[0]
    version = OPENEXR_REQUIREMENT.split("==")[1]
    wheels: list[str] = []
    for py in PYTHON_VERSIONS:
        tag = "cp" + py.replace(".", "")
        for platform in platforms:
            tags = PLATFORM_TAGS[platform]
            cached = [
                w
                for w in glob.glob(os.path.join(cache_dir, f"{name}-{version}-{tag}-*.whl"))
                if set(wheel_platform_tags(w)) & set(tags)
            ]
            if not cached:
                if offline:
                    raise BuildError(f"--offline and no cached {name} {version} wheel for {tag} {platform}")
                cmd = [
                    sys.executable, "-m", "pip", "download", "-q", "--disable-pip-version-check",
                    "--no-deps", "--only-binary=:all:", "--implementation", "cp",
                    "--python-version", py, "--abi", tag, "--dest", cache_dir,
                ]  # fmt: skip
                for t in tags:
                    cmd += ["--platform", t]
                cmd.append(OPENEXR_REQUIREMENT)
                before = set(os.listdir(cache_dir))
                result = subprocess.run(cmd, capture_output=True, text=True)
                if result.returncode != 0:
                    raise BuildError(
                        f"pip download {OPENEXR_REQUIREMENT} ({tag}, {platform}) failed: "
                        + (result.stderr.strip().splitlines() or ["?"])[-1]
                    )
                cached = [os.path.join(cache_dir, f) for f in set(os.listdir(cache_dir)) - before]
                if not cached:
                    raise BuildError(f"pip download produced no wheel for {tag} {platform}")
            wheel = sorted(cached)[0]
            if os.path.basename(wheel).lower().startswith("numpy-"):
                raise BuildError("numpy must never be bundled (Blender ships it)")
            if wheel not in wheels:
                wheels.append(wheel)
    return wheels


def _replace_list(text: str, key: str, items: list[str]) -> str:
    listing = f"{key} = [\n" + "".join(f'    "{item}",\n' for item in items) + "]"
    text, count = re.subn(rf"(?m)^{key}\s*=\s*\[[^\]]*\]", lambda _m: listing, text)
    if count != 1:
        raise BuildError(f"{MANIFEST} must contain exactly one '{key} = [...]' entry, found {count}")
    return text


def write_staged_manifest(staged: str, wheel_names: list[str], platforms: list[str]) -> None:
    """Fill ``wheels`` (and narrow ``platforms`` to those built) in the staged manifest."""
    path = os.path.join(staged, MANIFEST)
    with open(path, encoding="utf-8") as fh:
        text = fh.read()
    text = _replace_list(text, "wheels", [f"./wheels/{w}" for w in wheel_names])
    text = _replace_list(text, "platforms", platforms)
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(text)
    with open(path, "rb") as fh:
        parsed = tomllib.load(fh)
    if [os.path.basename(w) for w in parsed["wheels"]] != wheel_names or parsed["platforms"] != platforms:
        raise BuildError("staged manifest lists the wrong wheels or platforms")


def run_tool(bpy_python: str, tool: str, args: list[str]) -> None:
    cmd = [bpy_python, tool, *args]
    print("[build] " + " ".join(os.path.relpath(a, ROOT) if os.path.isabs(a) else a for a in cmd), file=sys.stderr)
    result = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    sys.stderr.write(result.stdout)
    sys.stderr.write(result.stderr)
    if result.returncode != 0:
        raise BuildError(f"blender_ext.py {args[0]} failed (exit {result.returncode})")


def build(
    *,
    bpy_python: str | None = None,
    output_dir: str | None = None,
    build_dir: str | None = None,
    platforms: list[str] | None = None,
    offline: bool = False,
    split_platforms: bool = True,
    wheels_cache: str | None = None,
) -> list[str]:
    """Stage, download wheels, validate and build; return the paths of the built zips.

    ``wheels_cache`` (default ``build/wheels-cache``) keeps downloaded wheels between builds, so a
    build whose cache is complete needs no network.
    """
    bpy_python = bpy_python or default_bpy_python()
    output_dir = os.path.abspath(output_dir or os.path.join(ROOT, "dist"))
    build_dir = os.path.abspath(build_dir or os.path.join(ROOT, "build"))
    with open(os.path.join(ROOT, MANIFEST), "rb") as fh:
        manifest = tomllib.load(fh)
    platforms = platforms or list(manifest["platforms"])
    unknown = sorted(set(platforms) - set(PLATFORM_TAGS))
    if unknown:
        raise BuildError(f"unknown platforms {unknown}; known: {sorted(PLATFORM_TAGS)}")

    tool = blender_ext_tool(bpy_python)
    staged = stage(build_dir)
    wheels_cache = wheels_cache or os.path.join(ROOT, "build", "wheels-cache")
    wheels = download_wheels(wheels_cache, platforms, offline)
    os.makedirs(os.path.join(staged, "wheels"), exist_ok=True)
    for w in wheels:
        shutil.copy2(w, os.path.join(staged, "wheels", os.path.basename(w)))
    write_staged_manifest(staged, [os.path.basename(w) for w in wheels], platforms)

    run_tool(bpy_python, tool, ["validate", staged])
    os.makedirs(output_dir, exist_ok=True)
    prefix = f"{manifest['id']}-{manifest['version']}"
    for old in glob.glob(os.path.join(output_dir, prefix + "*.zip")):
        os.remove(old)
    args = ["build", "--source-dir", staged, "--output-dir", output_dir]
    if split_platforms:
        args.append("--split-platforms")
    run_tool(bpy_python, tool, args)
    zips = sorted(glob.glob(os.path.join(output_dir, prefix + "*.zip")))
    if not zips:
        raise BuildError(f"extension build produced no {prefix}*.zip in {output_dir}")
    return zips


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="build_extension.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--bpy-python", help="Python of a venv with the bpy wheel (default: .venv/bpy-4.2, ...)")
    parser.add_argument("--output-dir", help="where the zips go (default: dist/)")
    parser.add_argument("--build-dir", help="staging directory (default: build/)")
    parser.add_argument("--platform", action="append", dest="platforms", help="limit to these Blender platforms")
    parser.add_argument("--offline", action="store_true", help="use only cached wheels (build/wheels-cache)")
    parser.add_argument("--no-split-platforms", action="store_true", help="one zip with every platform's wheels")
    args = parser.parse_args(argv)
    try:
        zips = build(
            bpy_python=args.bpy_python,
            output_dir=args.output_dir,
            build_dir=args.build_dir,
            platforms=args.platforms,
            offline=args.offline,
            split_platforms=not args.no_split_platforms,
        )
    except BuildError as ex:
        print(f"build_extension: error: {ex}", file=sys.stderr)
        return 1
    for z in zips:
        print(z)
    return 0


if __name__ == "__main__":
    sys.exit(main())
