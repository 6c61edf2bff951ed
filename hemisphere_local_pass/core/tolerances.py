"""Every tolerance of the numeric core, in one place.

All tolerances are *relative*: a distance is compared with the length scale of the
configuration it belongs to (the distance of the vertices from the receiver point, or the size
of a polygon), so results do not depend on the scene's units or on its distance from the origin.
"""

#: A point whose distance from a plane is at most ``PLANE_EPS`` times the local length scale lies
#: *on* the plane. Used to classify vertices against clip planes, and to decide that a receiver
#: point lies in the plane of a polygon (which then contributes nothing and hides nothing). For a
#: vertex against the horizon or a shadow-volume plane the scale is the vertex's own (its largest
#: P-local coordinate, plus the plane's offset): a vertex 1e-9 from P is not on a plane through P at
#: 1e-12 from it (1e-3 rad), however large its polygon.
PLANE_EPS = 1e-12

#: Polygons whose area is below ``AREA_EPS`` times the square of their longest edge (slivers,
#: collinear or repeated vertices) are degenerate: dropped from the scene and counted.
AREA_EPS = 1e-12

#: A polygon whose vertices deviate from their best-fit (Newell) plane by more than
#: ``PLANARITY_EPS`` times its size is non-planar and is triangulated (even when that is input
#: rounding: treated as planar, its vertices would not lie in its depth plane).
PLANARITY_EPS = 1e-12

#: Consecutive vertices closer than ``DUPLICATE_EPS`` times the polygon size are merged.
DUPLICATE_EPS = 1e-12

#: A polygon is convex when every turn of its boundary is left of the normal by at least
#: ``-CONVEXITY_EPS`` times the product of the two edge lengths.
CONVEXITY_EPS = 1e-12

#: Ray casting (:mod:`.raycast`): the default ``t_min`` is ``RAY_EPS`` times the ray's length scale
#: (distance of its origin from the scene's centre plus the scene's radius), in units of ``|d|``, so
#: rays leaving a surface do not hit it again through rounding (the self-hit ``t`` is ~1e-16 of that
#: scale over the cosine with the surface: grazing angles down to cos ~ 1e-7 are safe). Occluders
#: nearer than this are missed.
RAY_EPS = 1e-9

#: Input coordinates are only known to about ``COORD_EPS`` times their magnitude: a scene moved
#: (rotated, translated) into place, or exported, carries a few ulp of rounding in every world
#: coordinate, so exact coincidences (shared planes, points on edges) hold only to
#: ``COORD_EPS * max |x|``. This absolute *coordinate noise* is added to the relative tolerances
#: above wherever a decision compares world-space geometry: far from the origin (1e6 with a local
#: scale of 1) it is ~1e-9 of the local scale, far above ``PLANE_EPS``.
COORD_EPS = 16 * 2.220446049250313e-16
