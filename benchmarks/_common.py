"""Shared set-up of the benchmarks: Cornell boxes with a radiosity solution and camera-visible points.

The first pass is cached in ``~/.cache/hemisphere_local_pass/`` (``HLP_CACHE`` overrides): the small
box is solved directly (centre-to-polygon form factors with the exact core), the large one by one
gather at its patch centres from the solved small box (see ``scenes.radiosity.gathered_radiance``).
"""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from hemisphere_local_pass.core.raycast import build_bvh, cast_rays  # noqa: E402
from hemisphere_local_pass.scenes import (  # noqa: E402
    PAPER_SETTINGS,
    camera_rays,
    centroid_form_factors,
    cornell_box,
    gathered_radiance,
    radiosity,
)

CACHE = Path(os.environ.get("HLP_CACHE", Path.home() / ".cache" / "hemisphere_local_pass"))


def log(*args):
    print(*args, file=sys.stderr, flush=True)


def machine() -> str:
    """One line: date, uname, nproc, numpy version."""
    uname = " ".join(platform.uname()[:3] + (platform.uname().machine,))
    try:
        cpu = subprocess.run(["sh", "-c", "grep -m1 'model name' /proc/cpuinfo | cut -d: -f2"],
                             capture_output=True, text=True, check=False).stdout.strip()
    except OSError:
        cpu = "?"
    return (f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {uname}; {cpu}; nproc {os.cpu_count()}; "
            f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}; numpy {np.__version__}; "
            f"Python {platform.python_version()}")


def solved_radiance(key: str, box) -> np.ndarray:
    """Per-polygon radiance ``(n, 3)`` of ``box`` (``key`` in PAPER_SETTINGS), cached."""
    CACHE.mkdir(parents=True, exist_ok=True)
    path = CACHE / f"cornell_{key}_{box.n_polygons}.npz"
    if path.exists():
        return np.load(path)["radiance"]
    t = time.perf_counter()
    small = cornell_box(**PAPER_SETTINGS["small"])
    f = centroid_form_factors(small.scene(), small.centroids(), small.normals())
    lum_small = radiosity(small.vertices, small.polygons, small.reflectivity, small.emission, form_factor_matrix=f)
    if key == "small":
        lum = lum_small
    else:
        log(f"[setup] gathering the first pass at {box.n_polygons} patch centres (cached afterwards)")
        lum = gathered_radiance(small.scene(radiance=lum_small), box.centroids(), box.normals(),
                                box.reflectivity, box.emission)
    log(f"[setup] first pass for {key}: {time.perf_counter() - t:.1f} s")
    np.savez(path, radiance=lum)
    return lum


def case(key: str, n_points: int = 1024, seed: int = 0, jitter: bool = True):
    """A benchmark case.

    Returns ``(box, scene, points (m, 3), normals (m, 3), hit)`` where the scene carries the first-pass
    radiance and the points are camera-visible surface points (one per pixel of a square image of
    ``ceil(sqrt(n_points))`` pixels a side, jittered inside the pixel so that no point lies exactly on
    an edge, where the exact ΣF is legitimately 1/2).
    """
    box = cornell_box(**PAPER_SETTINGS[key])
    lum = solved_radiance(key, box)
    scene = box.scene(radiance=lum)
    side = int(np.ceil(np.sqrt(n_points)))
    o, d = camera_rays(box, side)
    if jitter:
        rng = np.random.default_rng(seed)
        cam = box.camera
        fwd, up = cam["direction"], cam["up"]
        right = np.cross(fwd, up)
        pix = 2 * np.tan(0.5 * cam["fov"]) / side
        d = d / d[:, 1:2]  # back on the image plane at distance 1
        d = d + (rng.uniform(-0.5, 0.5, (len(d), 1)) * right + rng.uniform(-0.5, 0.5, (len(d), 1)) * up) * pix
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        t0 = (1e-9 * box.size - cam["location"][1]) / d[:, 1]
        o = cam["location"] + t0[:, None] * d
    h = cast_rays(scene, o, d, bvh=build_bvh(scene))
    keep = np.flatnonzero(h.hit)[:n_points]
    points = h.point[keep]
    normals = scene.poly_normals[h.polygon[keep]]
    return box, scene, points, normals, h


def timed(fn, *args, **kw):
    """``(result, seconds)`` of one call."""
    t = time.perf_counter()
    out = fn(*args, **kw)
    return out, time.perf_counter() - t


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec. 709 luminance of ``(..., 3)`` linear RGB."""
    return rgb @ np.array([0.2126, 0.7152, 0.0722])


#: how a written ``--out`` markdown file's hand-written part begins: a new run rewrites what comes before
#: the line and keeps the rest (measurements and readings added by hand)
KEEP_PREFIX = "<!-- hand-written below:"


def keep_marker(script: str) -> str:
    """The marker line a benchmark ``script`` writes (see :data:`KEEP_PREFIX`)."""
    return f"{KEEP_PREFIX} kept when {script} --out rewrites this file -->"


def with_kept_sections(text: str, path) -> str:
    """``text`` followed by the hand-written part of the existing ``path`` (from its marker line on, any
    benchmark's: :data:`KEEP_PREFIX`), if it has one; a file without the marker is replaced whole."""
    path = Path(path)
    if not path.exists():
        return text
    old = path.read_text()
    at = old.find(KEEP_PREFIX)
    return text if at < 0 else text + "\n" + old[at:]
