"""Numerical stress test of the exact core (issue 3): random and adversarial configurations.

A configuration is one receiver (point, normal) in one generated scene; ``core.form_factors`` is
evaluated for every configuration. Scene families (each also translated to ~1e6 from the origin,
scaled by 1e-4…1e4, and/or with float32-rounded vertices):

* ``closed_box``: a cube split into quads and triangles, normals inward; receivers inside, on the faces
  (also exactly on the split lines and grid vertices), and on the cube's edges and corners with a
  limit direction into the face (the one-sided limit): closed, ΣF = 1.
* ``room_boxes``: a room with 5-20 random rotated, overlapping and interpenetrating closed boxes;
  receivers anywhere inside the room (also inside boxes): closed, ΣF = 1; plus receivers exactly on
  the boxes' vertices, edges and faces (range checks only: a receiver on an edge sees a discontinuity).
* ``coplanar_stack``: copies of a polygon stacked 0…1e-6 apart, shifted and turned slightly; receivers
  on, between and near the layers.
* ``slivers``: triangles of aspect ratio 1e-3…1e-12 among ordinary ones.
* ``scale_ratio``: polygons of size 1e-6 beside polygons of size 1e6 (ratio 1e12).
* ``grazing``: polygons within 1e-12…1e-3 rad of the receiver's tangent plane, some crossing it.
* ``soup``: random triangles and quads, receivers exactly on their vertices, edges and planes.

Reported: NaN/Inf count, F < 0 and F > 1 counts, ΣF > 1 + 1e-9 count (open scenes), max |ΣF − 1| in
closed scenes, and the max invariance error: |ΔF| after a random rigid motion, scaling (1e-4…1e4),
translation by 1e6 scene sizes, polygon reordering and cyclic vertex rotation (generic receivers only).

    OMP_NUM_THREADS=1 python benchmarks/stress.py --count 1000000 [--seed 0] [--out docs/stress.md]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from hemisphere_local_pass.core import Scene, form_factors  # noqa: E402

# ----------------------------------------------------------------------------------------- geometry


def _rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _hemisphere(normals, rng):
    """Random unit vectors in the hemispheres about ``normals (m, 3)``."""
    d = _unit(rng.normal(size=normals.shape))
    return np.where((np.einsum("mc,mc->m", d, normals) < 0)[:, None], -d, d)


class _Mesh:
    """Vertices and polygons with shared vertex indices."""

    def __init__(self):
        self.verts: list = []
        self.polys: list = []

    def add(self, pts) -> list[int]:
        base = len(self.verts)
        self.verts.extend(np.asarray(pts, dtype=np.float64))
        return list(range(base, base + len(pts)))

    def arrays(self):
        return np.array(self.verts, dtype=np.float64).reshape(-1, 3), self.polys


def _grid_box(mesh: _Mesh, lo, hi, n, rng, inward: bool, tri_fraction=0.5):
    """Axis-aligned box [lo, hi] with each face split n x n, some cells into triangles; shared vertices."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    index: dict = {}

    def vid(p):
        key = tuple(p)
        if key not in index:
            index[key] = mesh.add([p])[0]
        return index[key]

    g = [np.linspace(lo[a], hi[a], n + 1) for a in range(3)]
    for axis in range(3):
        u, w = (axis + 1) % 3, (axis + 2) % 3
        for side, val in ((0, lo[axis]), (1, hi[axis])):
            # outward normal is -axis on side 0, +axis on side 1; (u, w, axis) is right-handed
            flip = (side == 0) != inward
            for i in range(n):
                for j in range(n):
                    quad = []
                    for a, b in ((i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)):
                        p = [0.0, 0.0, 0.0]
                        p[axis], p[u], p[w] = val, g[u][a], g[w][b]
                        quad.append(vid(tuple(p)))
                    if flip:
                        quad = quad[::-1]
                    if rng.random() < tri_fraction:
                        if rng.random() < 0.5:
                            mesh.polys += [[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]]
                        else:
                            mesh.polys += [[quad[0], quad[1], quad[3]], [quad[1], quad[2], quad[3]]]
                    else:
                        mesh.polys.append(quad)
    return g


def _box_polys(mesh: _Mesh, centre, half, rot):
    """A closed box (6 quads, outward normals) with centre, half-sizes and rotation."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * half
    ids = mesh.add(corners @ rot.T + centre)
    faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    for f in faces:
        mesh.polys.append([ids[i] for i in f])
    return corners @ rot.T + centre


# ----------------------------------------------------------------------------------------- families


def closed_box(rng, k):
    mesh = _Mesh()
    n = int(rng.integers(1, 5))
    g = _grid_box(mesh, (0, 0, 0), (1, 1, 1), n, rng, inward=True)
    v, polys = mesh.arrays()
    m1 = k // 2
    p1 = rng.uniform(0.0, 1.0, (m1, 3))
    n1 = _unit(rng.normal(size=(m1, 3)))
    # receivers on faces, including exactly on the internal split lines and grid vertices
    m2 = k - m1
    axis = rng.integers(0, 3, m2)
    side = rng.integers(0, 2, m2).astype(float)
    p2 = rng.uniform(0.0, 1.0, (m2, 3))
    snap = rng.random((m2, 3)) < 0.3
    gi = g[0][rng.integers(1, n, (m2, 3))] if n > 1 else p2
    p2 = np.where(snap, gi, p2)
    lim = np.zeros((m2, 3))
    # a third on the cube's edges and corners, approached from inside the face
    edge = rng.random(m2) < 0.35
    rows = np.arange(m2)
    other = (axis + 1 + rng.integers(0, 2, m2)) % 3
    p2[rows, axis] = side
    p2[edge, other[edge]] = rng.integers(0, 2, edge.sum()).astype(float)
    nrm2 = np.zeros((m2, 3))
    nrm2[rows, axis] = np.where(side == 0, 1.0, -1.0)
    lim[edge, other[edge]] = np.where(p2[edge, other[edge]] == 0, 1.0, -1.0)
    lim[edge] += 0.3 * rng.uniform(-1, 1, (edge.sum(), 3)) * (np.arange(3)[None] != axis[edge, None]) * \
        (np.arange(3)[None] != other[edge, None])
    lim[edge] = _unit(lim[edge])
    p = np.concatenate([p1, p2])
    nn = np.concatenate([n1, nrm2])
    limit = np.concatenate([np.zeros((m1, 3)), lim])
    generic = np.concatenate([np.ones(m1, bool), np.zeros(m2, bool)])
    return v, polys, p, nn, limit, True, generic


def room_boxes(rng, k):
    mesh = _Mesh()
    _grid_box(mesh, (0, 0, 0), (1, 1, 1), 1, rng, inward=True, tri_fraction=0.0)
    corners = []
    for _ in range(int(rng.integers(5, 21))):
        half = rng.uniform(0.02, 0.2, 3)
        centre = rng.uniform(0.25, 0.75, 3)
        corners.append(_box_polys(mesh, centre, half, _rotation(rng)))
    v, polys = mesh.arrays()
    m1 = (2 * k) // 3
    p1 = rng.uniform(0.01, 0.99, (m1, 3))
    n1 = _unit(rng.normal(size=(m1, 3)))
    m2 = k - m1
    cs = np.concatenate(corners)  # box vertices
    pick = rng.integers(0, len(cs), (m2, 2))
    t = rng.choice([0.0, 0.5, rng.random()], size=m2)[:, None]
    p2 = cs[pick[:, 0]] * (1 - t) + cs[pick[:, 1]] * t  # vertices, edge and diagonal points
    n2 = _unit(rng.normal(size=(m2, 3)))
    p = np.concatenate([p1, p2])
    nn = np.concatenate([n1, n2])
    closed = np.concatenate([np.ones(m1, bool), np.zeros(m2, bool)])
    return v, polys, p, nn, None, closed, closed.copy()


def coplanar_stack(rng, k):
    mesh = _Mesh()
    base = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    layers = int(rng.integers(2, 8))
    for i in range(layers):
        delta = rng.choice([0.0, 1e-15, 1e-12, 1e-9, 1e-6]) * i
        ang = rng.choice([0.0, 1e-12, 1e-8, 1e-4])
        c, s = np.cos(ang), np.sin(ang)
        rot = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
        shift = rng.choice([0.0, 1e-9, 0.3]) * rng.uniform(-1, 1, 3) * [1, 1, 0]
        pts = base @ rot.T + shift + [0, 0, delta]
        ids = mesh.add(pts if rng.random() < 0.5 else pts[::-1])
        mesh.polys.append(ids)
    v, polys = mesh.arrays()
    p = rng.uniform(-0.2, 1.2, (k, 3))
    p[:, 2] = rng.choice([0.0, 1e-15, 1e-9, 1e-6, -1e-6, 0.5, -0.5], size=k)
    nn = _unit(rng.normal(size=(k, 3)))
    return v, polys, p, nn, None, np.zeros(k, bool), np.zeros(k, bool)


def slivers(rng, k):
    mesh = _Mesh()
    for _ in range(int(rng.integers(3, 20))):
        a = rng.uniform(-1, 1, 3)
        b = a + rng.normal(size=3)
        aspect = 10.0 ** rng.uniform(-12, -3)
        c = 0.5 * (a + b) + aspect * np.linalg.norm(b - a) * _unit(rng.normal(size=3))
        mesh.polys.append(mesh.add([a, b, c]))
    for _ in range(int(rng.integers(1, 6))):
        mesh.polys.append(mesh.add(rng.uniform(-1, 1, (3, 3))))
    v, polys = mesh.arrays()
    verts = v[rng.integers(0, len(v), k)]
    p = np.where(rng.random((k, 1)) < 0.3, verts, rng.uniform(-1.5, 1.5, (k, 3)))
    nn = _unit(rng.normal(size=(k, 3)))
    return v, polys, p, nn, None, np.zeros(k, bool), np.zeros(k, bool)


def scale_ratio(rng, k):
    mesh = _Mesh()
    for _ in range(int(rng.integers(2, 8))):
        size = 10.0 ** rng.choice([-6.0, 0.0, 6.0])
        centre = rng.uniform(-1, 1, 3) * rng.choice([1e-6, 1.0, 1e6])
        mesh.polys.append(mesh.add(centre + size * rng.normal(size=(3, 3))))
    v, polys = mesh.arrays()
    near = v[rng.integers(0, len(v), k)] + rng.normal(size=(k, 3)) * 10.0 ** rng.choice([-7.0, -5.0, 0.0], (k, 1))
    p = np.where(rng.random((k, 1)) < 0.7, near, rng.uniform(-2, 2, (k, 3)))
    nn = _unit(rng.normal(size=(k, 3)))
    return v, polys, p, nn, None, np.zeros(k, bool), np.zeros(k, bool)


def grazing(rng, k):
    mesh = _Mesh()
    for _ in range(int(rng.integers(2, 10))):
        ang = rng.choice([1e-12, 1e-9, 1e-6, 1e-3, -1e-9]) * rng.choice([1, -1])
        dist = rng.uniform(0.1, 10)
        h = dist * np.tan(ang) + rng.choice([0.0, 1e-12, -1e-12])
        x0 = rng.uniform(-dist, dist)
        pts = np.array([[x0, -1, h], [x0 + dist, -1, h + dist * np.tan(ang)],
                        [x0 + dist, 1, h + dist * np.tan(ang)], [x0, 1, h]])
        mesh.polys.append(mesh.add(pts if rng.random() < 0.5 else pts[::-1]))
    v, polys = mesh.arrays()
    p = np.zeros((k, 3)) + rng.normal(size=(k, 3)) * rng.choice([0.0, 1e-12, 1e-6], (k, 1))
    nn = _unit(np.array([0, 0, 1.0]) + rng.normal(size=(k, 3)) * rng.choice([0.0, 1e-9, 1e-3], (k, 1)))
    return v, polys, p, nn, None, np.zeros(k, bool), np.zeros(k, bool)


def soup(rng, k):
    mesh = _Mesh()
    for _ in range(int(rng.integers(2, 30))):
        c = rng.uniform(-1, 1, 3)
        if rng.random() < 0.5:
            mesh.polys.append(mesh.add(c + 0.5 * rng.normal(size=(3, 3))))
        else:
            rot = _rotation(rng)
            q = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float) * rng.uniform(0.1, 1, 3)
            mesh.polys.append(mesh.add(c + q @ rot.T))
    v, polys = mesh.arrays()
    which = rng.integers(0, 4, k)
    pid = rng.integers(0, len(polys), k)
    first = np.array([v[polys[i][0]] for i in pid])
    second = np.array([v[polys[i][1]] for i in pid])
    third = np.array([v[polys[i][2]] for i in pid])
    t = rng.random((k, 1))
    r2 = rng.normal(size=(k, 2))
    on_plane = first + r2[:, :1] * (second - first) + r2[:, 1:] * (third - first)
    p = np.select([which[:, None] == 0, which[:, None] == 1, which[:, None] == 2],
                  [first, first + t * (second - first), on_plane], rng.uniform(-1.5, 1.5, (k, 3)))
    nn = _unit(rng.normal(size=(k, 3)))
    return v, polys, p, nn, None, np.zeros(k, bool), which == 3


FAMILIES = {"closed_box": closed_box, "room_boxes": room_boxes, "coplanar_stack": coplanar_stack,
            "slivers": slivers, "scale_ratio": scale_ratio, "grazing": grazing, "soup": soup}

# ----------------------------------------------------------------------------------------- driver


def _transform(rng, v, p, n, limit, mode):
    """Apply a family-independent variant: far from the origin, scaled, float32-rounded."""
    if mode == "far":
        off = rng.uniform(-1, 1, 3) * 1e6
        v, p = v + off, p + off
    elif mode == "scaled":
        s = 10.0 ** rng.uniform(-4, 4)
        v, p = v * s, p * s
    elif mode == "float32":
        v = v.astype(np.float32).astype(np.float64)
        p = p.astype(np.float32).astype(np.float64)
        n = _unit(n.astype(np.float32).astype(np.float64))
    return v, p, n, limit


def _invariance(rng, v, polys, p, n, f, save_dir=None):
    """Max |ΔF| after a rigid motion + scaling + translation + reordering (generic receivers).

    The translation is 1e6 times the scene's size after scaling: a scene far from the origin keeps
    the same relative precision whatever its scale (about 1e6 ulp of its size). Families whose
    polygons differ in size by 1e12 (``scale_ratio``) lose the small polygons' digits to any motion:
    their invariance error measures input rounding, not the method (reported per family)."""
    rot = _rotation(rng)
    s = 10.0 ** rng.uniform(-4, 4)
    size = float(np.ptp(v, axis=0).max()) or 1.0
    off = rng.uniform(-1, 1, 3) * 1e6 * s * size
    v2 = (v @ rot.T) * s + off
    p2 = (p @ rot.T) * s + off
    n2 = n @ rot.T
    order = rng.permutation(len(polys))
    polys2 = []
    for i in order:
        q = list(polys[i])
        r = int(rng.integers(0, len(q)))
        polys2.append(q[r:] + q[:r])
    try:
        f2 = form_factors(Scene.from_polygons(v2, polys2), p2, n2)
    except Exception:
        _save_failure(save_dir, "exception_invariance", v2, polys2, p2, n2, None)  # the transformed input
        raise
    back = np.empty_like(f2)
    back[:, order] = f2
    err = float(np.abs(back - f).max()) if f.size else 0.0
    if err > 1e-6:  # keep a reproducer: the original and the transformed input
        _save_failure(save_dir, "invariance_original", v, polys, p, n, None)
        _save_failure(save_dir, "invariance_transformed", v2, polys2, p2, n2, None)
    return err


def _save_failure(save_dir, kind, v, polys, p, n, limit):
    """Keep the first failing scene of each kind as ``stress_<kind>.npz`` (a reproducer)."""
    if save_dir is None:
        return
    path = Path(save_dir) / f"stress_{kind}.npz"
    if path.exists():
        return
    loops = np.array([i for q in polys for i in q])
    counts = np.array([len(q) for q in polys])
    np.savez(path, vertices=v, loops=loops, counts=counts, points=p, normals=n,
             limit=np.zeros_like(p) if limit is None else limit)


def run(count: int, seed: int = 0, per_scene: int = 256, progress=None, save_dir=None) -> dict:
    """Evaluate ``count`` configurations; returns the statistics (dict). Failing scenes (exceptions,
    floating-point errors) are saved to ``save_dir`` when given."""
    rng = np.random.default_rng(seed)
    names = list(FAMILIES)
    stats = {"configurations": 0, "scenes": 0, "exceptions": 0, "fp_errors": 0, "nan_inf": 0, "negative": 0,
             "above_one": 0, "sum_above_one": 0, "closed_configurations": 0, "closed_sum_max_dev": 0.0,
             "invariance_checks": 0, "invariance_max": 0.0, "invariance_by_family": {}, "min_F": 0.0, "max_F": 0.0,
             "worst": {}}
    by_family = {nm: 0 for nm in names}
    t0 = time.perf_counter()
    while stats["configurations"] < count:
        name = names[stats["scenes"] % len(names)]
        k = min(per_scene, count - stats["configurations"])
        v, polys, p, n, limit, closed, generic = FAMILIES[name](rng, k)
        mode = rng.choice(["plain", "far", "scaled", "float32"])
        v, p, n, limit = _transform(rng, v, p, n, limit, mode)
        n = _unit(n)
        try:
            with np.errstate(all="raise"):  # a floating-point warning is a failure, as in the tests
                scene = Scene.from_polygons(v, polys)
                f = form_factors(scene, p, n, limit_directions=limit)
        except FloatingPointError as exc:
            stats["fp_errors"] += len(p)
            stats["worst"].setdefault("fp_error", f"{name}/{mode}: {exc}")
            _save_failure(save_dir, "fp_error", v, polys, p, n, limit)
            stats["configurations"] += len(p)
            stats["scenes"] += 1
            continue
        except Exception as exc:  # noqa: BLE001 — any crash of the core is a finding, keep going
            stats["exceptions"] += len(p)
            stats["worst"].setdefault("exception", f"{name}/{mode}: {type(exc).__name__}: {exc}")
            _save_failure(save_dir, "exception", v, polys, p, n, limit)
            stats["configurations"] += len(p)
            stats["scenes"] += 1
            continue
        bad = ~np.isfinite(f)
        stats["nan_inf"] += int(bad.sum())
        f = np.where(bad, 0.0, f)
        stats["negative"] += int((f < 0).sum())
        stats["above_one"] += int((f > 1).sum())
        stats["min_F"] = min(stats["min_F"], float(f.min()) if f.size else 0.0)
        stats["max_F"] = max(stats["max_F"], float(f.max()) if f.size else 0.0)
        sums = f.sum(axis=1)
        stats["sum_above_one"] += int((sums > 1 + 1e-9).sum())
        closed = np.broadcast_to(closed, (len(p),))
        if closed.any():
            dev = float(np.abs(sums[closed] - 1).max())
            stats["closed_configurations"] += int(closed.sum())
            if dev > stats["closed_sum_max_dev"]:
                stats["closed_sum_max_dev"] = dev
                stats["worst"]["closed_sum"] = f"{name}/{mode}"
        g = np.flatnonzero(generic)[:8]
        if len(g) and not scene.dropped and mode != "float32":
            try:
                err = _invariance(rng, v, polys, p[g], n[g], f[g], save_dir)
            except Exception as exc:  # noqa: BLE001
                stats["exceptions"] += len(g)
                stats["worst"].setdefault("exception", f"{name}/{mode} (invariance): {type(exc).__name__}: {exc}")
                err = 0.0
            stats["invariance_checks"] += len(g)
            fam = stats["invariance_by_family"]
            fam[name] = max(fam.get(name, 0.0), err)
            if err > stats["invariance_max"]:
                stats["invariance_max"] = err
                stats["worst"]["invariance"] = f"{name}/{mode}"
        stats["configurations"] += len(p)
        stats["scenes"] += 1
        by_family[name] += len(p)
        if progress is not None and stats["scenes"] % 50 == 0:
            progress(stats, time.perf_counter() - t0)
    stats["seconds"] = time.perf_counter() - t0
    stats["by_family"] = by_family
    return stats


def report(stats: dict) -> str:
    s = stats
    return "\n".join([
        f"configurations: {s['configurations']:,} in {s['scenes']:,} scenes ({s['seconds']:.0f} s); "
        f"by family: {s['by_family']}",
        f"NaN/Inf form factors: {s['nan_inf']}   floating-point errors (receivers): {s['fp_errors']}   "
        f"exceptions (receivers): {s['exceptions']}",
        f"F < 0: {s['negative']}   F > 1: {s['above_one']}   (min F {s['min_F']:.3e}, max F {s['max_F']:.17g})",
        f"ΣF > 1 + 1e-9: {s['sum_above_one']}",
        f"closed scenes: max |ΣF − 1| = {s['closed_sum_max_dev']:.3e} over {s['closed_configurations']:,} receivers",
        f"invariance (rigid motion, scale 1e-4..1e4, translation 1e6 sizes, reordering): max |ΔF| = "
        f"{s['invariance_max']:.3e} over {s['invariance_checks']:,} receivers; by family: "
        + ", ".join(f"{k} {v:.1e}" for k, v in s["invariance_by_family"].items()),
        f"worst cases: {s['worst']}",
    ])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--count", type=int, default=1_000_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None, help="also write the report (markdown) here")
    ap.add_argument("--save-failures", default=None, help="directory for reproducers of failing scenes (.npz)")
    args = ap.parse_args(argv)

    def progress(st, sec):
        print(f"  {st['configurations']:,} configurations, {sec:.0f} s, exceptions {st['exceptions']}, "
              f"NaN/Inf {st['nan_inf']}, "
              f"F<0 {st['negative']}, F>1 {st['above_one']}, closed max dev {st['closed_sum_max_dev']:.2e}, "
              f"invariance {st['invariance_max']:.2e}", file=sys.stderr, flush=True)

    if args.save_failures:
        Path(args.save_failures).mkdir(parents=True, exist_ok=True)
    stats = run(args.count, args.seed, progress=progress, save_dir=args.save_failures)
    text = report(stats)
    print(text)
    if args.out:
        sys.path.insert(0, str(Path(__file__).parent))
        from _common import machine

        with open(args.out, "w", encoding="utf-8") as fh:
            fh.write(f"# Stress test of the exact core\n\nMachine: {machine()}\n\n"
                     f"Command: `OMP_NUM_THREADS=1 python benchmarks/stress.py --count {args.count} "
                     f"--seed {args.seed}`\n\n```\n{text}\n```\n")
    bad = stats["nan_inf"] + stats["fp_errors"] + stats["exceptions"] + stats["negative"] + stats["above_one"]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
