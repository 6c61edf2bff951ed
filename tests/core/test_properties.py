"""Property-based robustness (Hypothesis): the degenerate configurations of real meshes.

Scenes are built on a half-integer grid (so that coincidences are exact): triangles and
parallelograms, pairs sharing an edge, T-junctions, coplanar overlapping duplicates (same,
reversed, shifted in-plane), slivers, and, relative to the receiver, grazing polygons (in or
within 1e-12...1e-6 of its tangent plane, or with the receiver in their plane, or next to it), tiny
(1e-6) and huge (1e6) polygons together. Receivers lie exactly on vertices, on edges (midpoints and
rational points), on faces, in a polygon's plane outside it, or anywhere; normals are axis directions,
polygon normals, in-plane (edge-on) directions or random; sometimes with a one-sided limit
direction. Half of the scenes are then moved by a rigid motion up to 1e6 from the origin (1e6 times
the polygons' size), so that exact coincidences hold only up to rounding. For every example: no
exception, no warning, no NaN, 0 <= F <= 1, sum F <= 1 + 1e-10, irradiance <= pi, and project_point
agrees with form_factors.

Failures found by this test are pinned as ``EXAMPLES`` (and in test_robustness_regressions.py).
The ``ci`` profile (loaded when CI is set, see conftest.py) runs >= 1000 examples.
"""


from __future__ import annotations

import warnings

import numpy as np
from hypothesis import HealthCheck, example, given, note, settings
from hypothesis import strategies as st
from scenes_for_tests import Mesh, box_face_quads, newell_normal, random_unit_vectors

GRID = st.integers(-4, 4)
SUM_TOL = 1e-10


def grid_point(draw, scale):
    return np.array([draw(GRID), draw(GRID), draw(GRID)], dtype=np.float64) * 0.5 * scale


def unit_vector(draw):
    v = np.array([draw(st.floats(-1, 1, allow_nan=False)) for _ in range(3)])
    n = np.linalg.norm(v)
    return v / n if n > 1e-3 else np.array([0.0, 0.0, 1.0])


def any_perpendicular(n, w):
    t = np.cross(n, w)
    if np.linalg.norm(t) < 1e-6:
        t = np.cross(n, [1.0, 0.0, 0.0])
        if np.linalg.norm(t) < 1e-6:
            t = np.cross(n, [0.0, 1.0, 0.0])
    return t / np.linalg.norm(t)


def add_feature(draw, polys, scale):
    kind = draw(st.sampled_from(["tri", "quad", "shared_edge", "t_junction", "duplicate", "sliver"]))
    A, B, C, D = (grid_point(draw, scale) for _ in range(4))
    if kind == "tri":
        polys.append([A, B, C])
    elif kind == "quad":
        polys.append([A, B, B + C - A, C])  # a parallelogram (planar)
    elif kind == "shared_edge":
        polys.append([A, B, C])
        polys.append([B, A, D] if draw(st.booleans()) else [A, B, D])  # consistent or flipped
    elif kind == "t_junction":
        M = 0.5 * (A + B)
        polys.append([A, B, C])
        polys.append([A, M, D])
        polys.append([M, B, D])
    elif kind == "duplicate" and polys:
        src = np.asarray(draw(st.sampled_from(polys)))
        how = draw(st.sampled_from(["same", "reversed", "shifted"]))
        if how == "same":
            polys.append(list(src))
        elif how == "reversed":
            polys.append(list(src[::-1]))
        else:
            shift = 0.5 * (src[1] - src[0]) * draw(st.sampled_from([0.5, 1.0, -0.25]))
            polys.append(list(src + shift))  # coplanar, overlapping
    else:  # sliver: C barely off the line AB
        t = draw(st.sampled_from([0.0, 0.25, 0.5, 1.0, 2.0]))
        eps = draw(st.sampled_from([1e-4, 1e-7, 1e-10, 1e-13]))
        off = np.cross(B - A, C - A)
        off = np.cross(off, B - A) if np.linalg.norm(off) > 0 else np.array([0.0, 0.0, 1.0])
        n = np.linalg.norm(off)
        off = off / n if n > 0 else np.array([0.0, 0.0, 1.0])
        polys.append([A, B, A + t * (B - A) + eps * np.linalg.norm(B - A) * off])


def choose_receiver(draw, polys, scale):
    poly = np.asarray(draw(st.sampled_from(polys))) if polys else None
    kind = draw(st.sampled_from(["vertex", "edge_mid", "edge_param", "face", "plane", "free"]))
    if poly is None:
        kind = "free"
    k = len(poly) if poly is not None else 0
    i = draw(st.integers(0, max(k - 1, 0)))
    if kind == "vertex":
        P = poly[i].copy()
    elif kind == "edge_mid":
        P = 0.5 * (poly[i] + poly[(i + 1) % k])
    elif kind == "edge_param":
        t = draw(st.integers(0, 8)) / 8.0
        P = poly[i] + t * (poly[(i + 1) % k] - poly[i])
    elif kind == "face":
        w = np.array([draw(st.integers(0, 4)) for _ in range(k)], dtype=np.float64)
        w[0] += 1.0
        P = (w / w.sum()) @ poly
    elif kind == "plane":  # in the polygon's plane, possibly outside it
        s, t = draw(st.integers(-3, 3)) / 2.0, draw(st.integers(-3, 3)) / 2.0
        P = poly[0] + s * (poly[1] - poly[0]) + t * (poly[-1] - poly[0])
    else:
        P = grid_point(draw, scale) + np.array([0.1, 0.2, 0.3]) * scale
    nk = draw(st.sampled_from(["axis", "poly", "edge_on", "random"]))
    pn = newell_normal(poly) if poly is not None else np.zeros(3)
    if nk == "poly" and np.linalg.norm(pn) > 0:
        N = pn / np.linalg.norm(pn) * draw(st.sampled_from([1.0, -1.0]))
    elif nk == "edge_on" and np.linalg.norm(pn) > 0:
        N = any_perpendicular(pn / np.linalg.norm(pn), unit_vector(draw))
    elif nk == "random":
        N = unit_vector(draw)
    else:
        N = np.zeros(3)
        N[draw(st.integers(0, 2))] = draw(st.sampled_from([1.0, -1.0]))
    U = np.zeros(3)
    if draw(st.booleans()):
        U = any_perpendicular(N, unit_vector(draw))
    return P, N, U


def add_relative_to_receiver(draw, polys, P, N, scale):
    """Grazing, tiny and huge polygons placed relative to the receiver."""
    t = any_perpendicular(N, [0.3, 0.7, 0.1])
    b = np.cross(N, t)
    for kind in draw(st.lists(st.sampled_from(["grazing", "through_p", "tiny", "huge", "enclosing"]), max_size=3)):
        if kind == "grazing":  # in or just off the tangent plane
            h = draw(st.sampled_from([0.0, 1e-12, -1e-12, 1e-9, 1e-6])) * scale
            c = P + h * N + draw(st.sampled_from([0.0, 0.5, 2.0])) * scale * t
            polys.append([c, c + scale * t, c + scale * (t + b), c + scale * b])
        elif kind == "through_p":  # a tilted polygon at P (its plane contains P when o = P) or next to it
            d = any_perpendicular(N, t) if draw(st.booleans()) else t
            up = (N + d) / np.linalg.norm(N + d)
            o = P + draw(st.sampled_from([0.0, 0.25, 1.0])) * scale * d
            side = np.cross(up, d)
            polys.append([o - scale * side, o + scale * side, o + scale * (side + up), o + scale * (up - side)])
        elif kind == "tiny":
            s = 1e-6
            c = P + draw(st.sampled_from([1e-6, 3e-6, 1e-5])) * (N + 0.3 * t)
            polys.append([c, c + s * t, c + s * b])
        elif kind == "huge":
            s = 1e6
            c = P + draw(st.sampled_from([1e3, 1e5])) * N - 0.5 * s * (t + b)
            polys.append([c, c + s * t, c + s * (t + b), c + s * b])
        else:  # huge, partly below the horizon and close by
            s = 1e6
            c = P + 2.0 * scale * N + 0.5 * s * (t - N)
            polys.append([c, c + s * b, c + s * (b - t), c - s * t])


@st.composite
def robust_cases(draw):
    scale = draw(st.sampled_from([1.0, 1.0, 1e-6, 1e6, 3.7e-3]))
    polys = []
    for _ in range(draw(st.integers(1, 5))):
        add_feature(draw, polys, scale)
    receivers = [choose_receiver(draw, polys, scale) for _ in range(draw(st.integers(1, 3)))]
    add_relative_to_receiver(draw, polys, receivers[0][0], receivers[0][1], scale)
    mesh = Mesh()
    for p in polys:
        mesh.add(np.asarray(p, dtype=np.float64), (1.0, 0.5, 0.25))
    verts, idx = mesh.arrays()
    P, N, U = (np.array(x, dtype=np.float64) for x in zip(*receivers, strict=True))
    if draw(st.booleans()):
        # a rigid motion: exact coincidences become coincidences up to rounding
        q = np.array([draw(st.floats(-1, 1, allow_nan=False)) for _ in range(4)])
        q = q / np.linalg.norm(q) if np.linalg.norm(q) > 1e-3 else np.array([1.0, 0.0, 0.0, 0.0])
        w, x, y, z = q
        R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                      [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                      [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        # translations up to 1e6 (and up to 1e6 times the polygons' size)
        t = np.array([draw(st.sampled_from([0.0, 1.0, 1e3, 1e6, -1e6])) for _ in range(3)]) * min(scale, 1.0)
        verts, P = verts @ R.T + t, P @ R.T + t
        N, U = N @ R.T, U @ R.T
    double = draw(st.booleans())
    return verts, idx, P, N, U, double


def _case(verts, idx, P, N, U, double=False):
    return (np.array(verts, dtype=np.float64), idx, np.array(P, dtype=np.float64), np.array(N, dtype=np.float64),
            np.array(U, dtype=np.float64), double)


# failures found by this test, kept as explicit examples
EXAMPLES = [
    # a parallelogram and its reversed coplanar copy, receiver at a vertex, limit along +x
    _case([[0, 0, 0], [0, 0, -0.5], [-0.5, 0.5, -1.0], [-0.5, 0.5, -0.5]], [[0, 1, 2, 3], [3, 2, 1, 0], [0, 0, 0]],
          [[-0.5, 0.5, -0.5]], [[0.0, -1.0, 0.0]], [[1.0, 0.0, 0.0]]),
    # two identical slivers; the receiver on an edge, 2.5e-12 (relative) off their plane by rounding
    _case([[0.5, 0.0, 0.5], [-2.0, 0.5, 0.0], [-0.12499996464466094, 0.12499992928932188, 0.37499975251262657],
           [0.0, 0.0, 0.0]], [[0, 1, 2], [0, 1, 2], [3, 3, 3], [3, 3, 3]],
          [[-1.0624999823223304, 0.31249996464466095, 0.18749987625631329]],
          [[-0.2357022603997991, -0.9428090415786368, 0.23570226040493902]], [[0.0, 0.0, 0.0]]),
    # a triangle and a sliver; the receiver on the sliver's edge, N = the sliver's normal, U (almost) in its
    # plane: in the limit the sliver counts (F = 0.936) but does not hide the triangle (sum 1.0745)
    _case([[0.0, 0.0, 0.0], [0.0, 0.0, 0.5], [0.0, 0.5, 0.5], [0.0, 0.0, 1.0], [0.5, 0.5, 0.0],
           [0.4999999672673165, 0.4999999018019494, -6.54653670707977e-08]], [[0, 1, 2], [3, 4, 5]],
          [[0.18749998772524368, 0.18749996317573103, 0.6249999754504875]],
          [[-0.8728715609593893, 0.43643578041030573, -0.21821789029767144]],
          [[0.24253562509682042, 0.0, -0.9701425001302101]]),
    # two adjacent triangles through P, within ~3e-11 of its tangent plane (far from the origin):
    # limit sum F = 1.0000034
    _case([[0.0, 0.0, 1000000.0], [0.0, -0.39999999999999997, 1000000.3], [0.0, 0.39999999999999997, 999999.7],
           [-0.4999999999999999, 0.30000000000000004, 1000000.4]],
          [[0, 0, 0], [0, 0, 0], [1, 2, 0], [1, 0, 3], [0, 2, 3]],
          [[0.0, 0.0, 1000000.0]], [[0.7071067811865475, 0.4242640687119286, 0.565685424949238]],
          [[-0.7071067811865475, 0.4242640687119286, 0.565685424949238]]),
    # IndexError in clipping.split_convex (via visibility.subtract_shadow_volumes) with a limit direction
    _case([[0.0, 0.0, 0.0],
           [0.0, -1987182.0548768272, 1025235.3294677734],
           [0.0, -403765.2713799319, -294912.8780517578],
           [0.0, -1195473.6631283795, 365161.2257080078],
           [500000.0, -294912.8780292408, 403765.2713623047],
           [250000.0, -745193.2705788101, 384463.24853515625],
           [-350271.2897108033, -1465828.0804279, 37534.07775878906],
           [-561070.4441465685, -904842.0306892704, -763002.2229003906],
           [39200.84556423471, -184207.22084018047, -416073.0520019531]],
          [[0, 0, 0], [0, 0, 0], [1, 2, 0], [1, 3, 4], [3, 2, 4], [5, 6, 7, 8]],
          [[250000.0, -745193.2705788101, 384463.24853515625]],
          [[0.7715167498104596, -0.4074065817244658, -0.48865302815954265]],
          [[-0.19611613513818402, 0.5783717384157337, -0.7918488452605227]]),
    # tiny (1e-6) polygons, sum F = 1.00028 at the second receiver (with a limit direction)
    _case([[0.0, 0.0, 0.0], [0.0, 0.0, 5e-07], [0.0, -5e-07, 0.0], [0.0, 1.5e-06, 1.5e-06],
           [-1.9999999949504854e-06, -2e-06, 5e-07], [1.9999999949504854e-06, 0.0, 5e-07],
           [9.999999974752427e-07, -4.242640687119286e-08, 2.9698484809834996e-07],
           [9.999999974752427e-07, -1.8384776310850236e-07, 1.2869343417595165e-06],
           [9.999999974752427e-07, -1.0323759005323595e-06, 1.5556349186104045e-07]],
          [[0, 1, 2], [0, 0, 0], [0, 0, 0], [3, 4, 5], [0, 0, 0], [6, 7, 8]],
          [[0.0, 0.0, 0.0], [-9.999999974752427e-07, -2.4999999999999994e-07, 1e-06], [0.0, 0.0, 0.0]],
          [[1.0, 0.0, 0.0], [0.18257418583505539, -0.36514837167011077, 0.9128709291752769], [1.0, 0.0, 0.0]],
          [[0.0, 0.0, 0.0], [-0.894427190999916, -0.447213595499958, 0.0], [0.0, 0.0, 0.0]]),
    # IndexError in clipping.split_convex without a limit direction: tiny (1e-6) triangles and a quad
    _case([[0.0, 0.0, 0.0], [0.0, 0.0, 5e-07], [-5.248614343145164e-08, -4.972375690607735e-07, 0.0],
           [0.0, 0.0, 1.5e-06], [2.093922603307874e-06, 7.845303867403315e-07, 0.0],
           [6.022099796609837e-07, 9.419889502762432e-07, -5.000000000000001e-07],
           [-1.491712737333728e-06, 1.5745856353591161e-07, 1e-06]],
          [[0, 1, 2], [0, 0, 0], [0, 0, 0], [3, 4, 5, 6], [0, 0, 0]],
          [[0.0, 0.0, 0.0], [1.046961301653937e-06, 3.9226519337016577e-07, 7.5e-07], [0.0, 0.0, 0.0]],
          [[0.9944751381215471, -0.10497237569060774, 0.0],
           [-0.043184383655727354, 0.9087828702063678, 0.4150286783196447],
           [-0.9944751381215471, 0.10497237569060774, 0.0]],
          [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]),
    # project_point's polygon form factor 1 + 7.9e-10 vs form_factors' 1.0 (F > 1 in project_point)
    _case([[-0.0037, 0.0, 0.0], [0.00185, -0.00185, 0.00555],
           [-0.0009249999994484142, -0.0009250000000894464, 0.002774999999418599],
           [-0.0023125000000000003, -0.0004625, 0.0013875], [0.0032375, -0.0023125000000000003, 0.0069375],
           [0.0004625000005515858, -0.0013875000000894465, 0.004162499999418599], [0.0, 0.0, 0.0]],
          [[0, 1, 2], [3, 4, 5], [6, 6, 6], [6, 6, 6], [6, 6, 6]],
          [[-0.00023124999986210356, -0.0011562500000223616, 0.0034687499998546497]],
          [[-0.24174684186082954, -0.9669875662685498, -0.08058232518575034]],
          [[0.0, 0.0, 0.0]]),
    # a sliver and a receiver on its edge at scale 3.7e-3: sum F = 1.0082
    _case([[-0.0037, 0.0, 0.0], [0.00185, 0.00185, 0.00185],
           [-0.0009249998648951025, 0.0009249994258041856, 0.0009250001688811219],
           [-0.0023125000000000003, 0.0004625, 0.0004625], [0.0032375, 0.0023125000000000003, 0.0023125000000000003],
           [0.00046250013510489756, 0.0013874994258041857, 0.001387500168881122], [0.0, 0.0, 0.0]],
          [[0, 1, 2], [3, 4, 5], [6, 6, 6], [6, 6, 6], [6, 6, 6]],
          [[-0.000925, 0.000925, 0.000925]],
          [[-0.36514837166409003, 0.18257418584462198, 0.9128709291757718]],
          [[0.0, 0.0, 0.0]]),
    # two nearly coplanar triangles sharing an edge (rounded) 1e6 from the origin: sum F = 1 + 1.5e-9
    _case([[0.0, 0.0, 1000000.0], [-0.45050593928728555, 0.2111746590409151, 1000000.0494940607],
           [-0.22525296964364278, 0.10558732952045755, 1000000.0247470303],
           [-0.2111746590409151, -0.40101187857457105, 999999.7888253409]],
          [[0, 0, 0], [0, 0, 0], [0, 1, 0], [0, 2, 3], [2, 1, 3], [0, 0, 0], [0, 0, 0]],
          [[-0.21821381434227893, -0.14771227452705676, 999999.9067861857], [0.0, 0.0, 1000000.0]],
          [[0.0989881214254289, 0.4223493180818302, -0.9010118785745711],
           [0.0989881214254289, 0.4223493180818302, -0.9010118785745711]],
          [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]),
    # tiny (1e-6) triangle next to the receiver, a huge (1e6) quad and a unit quad: the tiny triangle hides the
    # unit quad but not the huge one (each pair alone is fine): sum F = 1.0423
    _case([[6.774023548972473e-07, 0.9999992631887925, 2.970442628930023e-07],
           [5.783876005995799e-07, 0.9999991641740382, 1.2871918058696766e-06],
           [-2.2737687116757593e-08, 0.9999985630487505, 1.570162544902013e-07],
           [400284.50493702275, 398871.2913746497, -425059.76728693664],
           [301269.7506393553, 299856.5370769822, 565087.7756897376],
           [-398870.2913746497, -400283.50493702275, 425059.76728693664],
           [-299855.53707698215, -301268.7506393552, -565087.7756897376],
           [7.071067811865476e-07, 0.9999992928932188, 0.0],
           [-0.09901404719088626, 0.9009845385955513, 0.9901475429766743],
           [-0.7991540892048912, 0.20084449658154635, 0.8501195345738732],
           [-0.7001393349072237, 0.29985925087921383, -0.140028008402801]],
          [[0, 1, 2], [3, 4, 5, 6], [7, 8, 9, 10]],
          [[0.0, 1.0, 0.0]], [[0.7071067811865476, -0.7071067811865476, 0.0]], [[0.0, 0.0, 0.0]]),
    # tiny (1e-6) triangle 5e5 from the origin before a huge quad: its plane is uncertain to ~1e-3 rad, the
    # quad 1e3 behind it must still be hidden (a one-sided coplanarity test dropped the pair)
    _case([[0.0, 0.0, 500000.0],
           [0.0, 0.0, 0.0],
           [1000.0, 565685.424949238, 75735.9312880715],
           [1000.0, 424264.06871192844, 1065685.424949238],
           [1000.0, -565685.424949238, 924264.0687119286],
           [1000.0, -424264.0687119287, -65685.42494923802],
           [1e-06, -4.242640687119286e-08, 500000.000000297],
           [1e-06, -1.8384776310850236e-07, 500000.0000012869],
           [1e-06, -1.0323759005323595e-06, 500000.00000015553]],
          [[0, 1, 1], [2, 3, 4, 5], [6, 7, 8]],
          [[0.0, 0.0, 500000.0]],
          [[1.0, 0.0, 0.0]],
          [[0.0, 0.0, 0.0]]),
    # a sliver (1e-4) with P on its short edge, limit off its plane, before a huge quad: sum F = 1.138
    _case([[0.5, 0.0, 0.5],
           [0.0, 0.0, -0.5],
           [0.4999, 0.0, 0.50005],
           [0.0, 0.0, 0.0],
           [1000.499925, 565685.424949238, -424263.5686744285],
           [1000.499925, 424264.06871192844, 565685.9249867381],
           [1000.499925, -565685.424949238, 424264.5687494285],
           [1000.499925, -424264.0687119287, -565684.924911738]],
          [[0, 1, 2], [3, 3, 3], [3, 3, 3], [4, 5, 6, 7]],
          [[0.499925, 0.0, 0.5000375]],
          [[1.0, 0.0, 0.0]],
          [[0.0, -1.0, 0.0]]),
    # the same with a 1e-10 short edge 1e3 from the origin: sum F = 1 + 1.6e-5
    _case([[0.0, 0.0, 1000.0],
           [0.0, 1.5, 999.5],
           [0.0, -5e-11, 999.99999999985],
           [316227.7660168379, 999.999999999975, 633455.5320336758],
           [632455.5320336758, 999.999999999975, -315227.7660168379],
           [-316227.7660168379, 999.999999999975, -631455.532033676],
           [-632455.5320336758, 999.999999999975, 317227.76601683785]],
          [[0, 1, 2], [0, 0, 0], [0, 0, 0], [3, 4, 5, 6]],
          [[0.0, -2.5e-11, 999.999999999925]],
          [[0.0, 1.0, 0.0]],
          [[1.0, 0.0, 0.0]]),
    # the same, short edge 1e-10 with P at its midpoint: sum F = 1.00057
    _case([[0.0, -0.5, 1000.5],
           [0.5, 0.0, 1000.0],
           [-7.071067811865477e-11, -0.49999999996464467, 1000.4999999999646],
           [0.0, 0.0, 1000.0],
           [999.9999999999646, 565684.924949238, -423263.5687119285],
           [999.9999999999646, 424263.56871192844, 566685.9249492381],
           [999.9999999999646, -565685.924949238, 425264.5687119285],
           [999.9999999999646, -424264.5687119287, -564684.9249492381]],
          [[0, 1, 2], [3, 3, 3], [3, 3, 3], [4, 5, 6, 7]],
          [[-3.535533905932738e-11, -0.49999999998232236, 1000.4999999999824]],
          [[1.0, 0.0, 0.0]],
          [[0.0, -1.0, 0.0]]),
    # P on the shared edge of two coplanar triangles 1e6 from the origin, limit off their plane: sum F = 1.448
    _case([[0.0, 0.0, 1000000.0],
           [0.0, -0.39999999999999997, 1000000.3],
           [-0.4999999999999999, 0.39999999999999997, 999999.7],
           [-0.24999999999999994, 0.0, 1000000.0],
           [0.0, 0.30000000000000004, 1000000.4],
           [-0.12499999999999997, 0.15000000000000002, 1000000.2],
           [-0.12499999999999997, 0.8571067811865475, 999999.4928932188],
           [-0.12499999999999997, 0.1499999999999998, 999998.7857864376],
           [-0.12499999999999997, -0.5571067811865477, 999999.4928932188]],
          [[0, 0, 0], [0, 0, 0], [1, 2, 0], [1, 3, 4], [3, 2, 4], [0, 0, 0], [5, 6, 7, 8]],
          [[-0.12499999999999997, 0.15000000000000002, 1000000.2], [0.0, 0.0, 1000000.0], [0.0, 0.0, 1000000.0]],
          [[-0.9999999999999998, 0.0, 0.0], [-0.9999999999999998, 0.0, 0.0], [-0.9999999999999998, 0.0, 0.0]],
          [[0.0, -0.6000000000000001, -0.7999999999999999], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]),
    # a sliver wall through P (limit off its plane) hides half of a 1e-6 triangle 1e-6 above P: the
    # sliver's far vertex (0.5 away) set the "strictly below" tolerance of its vertex at P: sum F = 1.03
    _case([[0.0, 0.0, 1000.0], [0.0, 0.5, 1000.0], [0.0, 0.0, 1000.00005],
           [-2.757435090054174e-07, 1.181757895737503e-07, 1000.000001],
           [-1.1948885390234753e-06, 5.120950881529179e-07, 1000.000001],
           [-6.696628075845851e-07, -8.009692404443076e-07, 1000.000001],
           [656532.1642986129, 262612.8657194451, 2000.0], [-262612.86571944505, 656532.1642986129, 2000.0],
           [-656532.1642986129, -262612.8657194451, 2000.0], [262612.86571944517, -656532.1642986129, 2000.0]],
          [[0, 1, 2], [3, 4, 5], [6, 7, 8, 9]],
          [[0.0, 0.0, 1000.0], [0.0, 0.0, 1000.0]],
          [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]],
          [[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]),
    # the same with P on the middle of the sliver's base and the triangle above it: the base vertices are
    # 1e-6 below the triangle's plane but within its uncertainty (1e-6 triangle 1e3 from the origin, 0.25
    # away): "strictly" culled the pair, F = 0.067 instead of 0 (sum F = 1.067)
    _case([[0.0, 0.0, 1000.0], [0.0, 0.5, 1000.0], [0.0, 0.0, 1000.00005],
           [-2.757435090054174e-07, 0.2500001181757896, 1000.000001],
           [-1.1948885390234753e-06, 0.25000051209508817, 1000.000001],
           [-6.696628075845851e-07, 0.24999919903075957, 1000.000001],
           [656532.1642986129, 262613.1157194451, 2000.0], [-262612.86571944505, 656532.4142986129, 2000.0],
           [-656532.1642986129, -262612.6157194451, 2000.0], [262612.86571944517, -656531.9142986129, 2000.0]],
          [[0, 1, 2], [3, 4, 5], [6, 7, 8, 9]],
          [[0.0, 0.25, 1000.0], [0.0, 0.0, 1000.0]],
          [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]],
          [[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]),
    # four triangles 1e6 from the origin, a receiver facing away from them all: nothing is seen, and
    # the signed sums left H = -5.8e-22 (now clamped at 0)
    _case([[0.0, -1.7647058823529411, 1000000.9411764706], [0.0, -0.47058823529411764, 999999.1176470588],
           [0.5, 0.4411764705882353, 999999.7647058824], [0.0, -1.1176470588235294, 1000000.0294117647],
           [0.0, 0.0, 1000000.0], [0.0, -0.23529411764705882, 999999.5588235294],
           [0.5, -0.23529411764705882, 999999.5588235294]],
          [[0, 1, 2], [0, 3, 4], [3, 1, 4], [4, 5, 6]],
          [[0.0, -1.7647058823529411, 1000000.9411764706], [0.5, 0.4411764705882353, 999999.7647058824],
           [0.0, -1.7647058823529411, 1000000.9411764706]],
          [[0.9128709291752769, -0.3329293976992186, -0.23627247578654223],
           [0.9128709291752769, -0.3329293976992186, -0.23627247578654223], [-1.0, 0.0, 0.0]],
          [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]),
]


@settings(suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much])
@given(robust_cases())
@example(EXAMPLES[0])
@example(EXAMPLES[1])
@example(EXAMPLES[2])
@example(EXAMPLES[3])
@example(EXAMPLES[4])
@example(EXAMPLES[5])
@example(EXAMPLES[6])
@example(EXAMPLES[7])
@example(EXAMPLES[8])
@example(EXAMPLES[9])
@example(EXAMPLES[10])
@example(EXAMPLES[11])
@example(EXAMPLES[12])
@example(EXAMPLES[13])
@example(EXAMPLES[14])
@example(EXAMPLES[15])
@example(EXAMPLES[16])
@example(EXAMPLES[17])
@example(EXAMPLES[18])
def test_robustness(core, case):
    verts, idx, P, N, U, double = case
    note(f"full precision: verts={verts.tolist()!r} polygons={idx!r} P={P.tolist()!r} N={N.tolist()!r} "
         f"U={U.tolist()!r} double_sided={double}")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene = core.Scene.from_polygons(verts, idx, np.tile([1.0, 0.5, 0.25], (len(idx), 1)), double_sided=double)
        U_arg = U if np.any(U) else None
        F = core.form_factors(scene, P, N, limit_directions=U_arg)
        H = core.irradiance(scene, P, N, limit_directions=U_arg)
        proj = core.project_point(scene, P[0], N[0], limit_direction=U[0] if np.any(U[0]) else None)
    assert F.shape == (len(P), len(idx))
    assert np.all(np.isfinite(F)), F
    assert F.min() >= 0.0, f"F = {F.min()!r} < 0"
    assert F.max() <= 1.0, f"F = {F.max()!r} > 1"
    sums = F.sum(axis=1)
    assert np.all(sums <= 1.0 + SUM_TOL), f"sum F = {sums.tolist()}"
    assert H.shape == (len(P), 3) and np.all(np.isfinite(H)) and H.min() >= 0.0, H
    assert np.all(H <= np.pi * (1.0 + SUM_TOL)), f"H = {H.tolist()} > pi"  # radiance <= 1: H = pi sum L F <= pi
    pff = np.asarray(proj.polygon_form_factors)
    assert np.all(np.isfinite(pff))
    np.testing.assert_allclose(pff, F[0], rtol=0, atol=1e-12)
    for frag in proj.fragments:
        assert np.all(np.isfinite(np.asarray(frag)))


def test_coplanar_duplicates_in_closed_box(core, rng):
    """Coplanar overlapping copies of the walls of a closed box: a surface seen twice is still seen once.

    Same-orientation copies (identical, cyclically shifted, an overlapping half-wall) keep sum F = 1
    to 1e-10; adding reversed copies (whose backs face the inside) must still keep sum F <= 1 + 1e-10.
    """
    mesh = Mesh()
    quads = box_face_quads([0.0, 0.0, 0.0], [1.0, 1.5, 1.25], inward=True)
    for q in quads:
        mesh.add(q)
    for q in quads:
        mesh.add(q)  # identical copy (the same vertex indices)
        mesh.add(np.roll(q, 1, axis=0))  # cyclically shifted copy
        mesh.add(np.array([q[0], 0.5 * (q[0] + q[1]), 0.5 * (q[2] + q[3]), q[3]]))  # overlapping half
    verts, polys = mesh.arrays()
    m = 300
    P = rng.uniform(0.01, 0.99, size=(m, 3)) * [1.0, 1.5, 1.25]
    N = random_unit_vectors(rng, m)
    F = core.form_factors(core.Scene.from_polygons(verts, polys), P, N)
    s = F.sum(axis=1)
    worst = int(np.argmax(np.abs(s - 1)))
    assert np.abs(s - 1).max() <= SUM_TOL, f"sum F = {s[worst]!r} at P={P[worst].tolist()} N={N[worst].tolist()}"
    for q in quads:
        mesh.add(q[::-1])  # reversed copies
    verts, polys = mesh.arrays()
    F = core.form_factors(core.Scene.from_polygons(verts, polys), P, N)
    assert F.min() >= 0.0 and F.sum(axis=1).max() <= 1.0 + SUM_TOL, F.sum(axis=1).max()
