"""Diffuse radiosity by progressive refinement (shooting) with exact form factors and O(n) memory.

Radiance form of the radiosity equation (B = π L), per RGB channel, for patches j = input polygons:

    L_j = E_j + ρ_j Σ_i F_ji L_i,        A_j F_ji = A_i F_ij  (reciprocity)

Progressive refinement (Cohen, Chen, Wallace & Greenberg 1988) keeps every patch's *unshot* radiance
ΔL (initially E). A step takes the patches with the most unshot power ``ΔΦ_i = s_i π A_i ΔL_i``
(``s_i`` = 1, or 2 for double-sided patches), sets their ΔL to 0 and distributes ΔΦ_i over the scene
with the patch-to-patch factors F_ij of :mod:`.quadrature` (several exact point-to-polygon
evaluations of the core per shooter, occlusion included): patch j receives ``ΔΦ_i F_ij`` and reflects

    ΔL_j += ρ_j ΔΦ_i F_ij / (s_j π A_j)   ( = ρ_j F_ji ΔL_i  by reciprocity).

Only the shooters' rows of F exist at any time: memory is O(Q n) for the Q ≤ ``max_points``
quadrature points of a step, i.e. O(n). Light reaching a single-sided patch's back is absorbed there
(a back face neither emits nor reflects, as in the local pass), light leaving an open scene escapes;
both are counted.

**Stopping criterion**: the unshot power ``U = Σ_i ΔΦ_i`` (summed over RGB) is at most ``tolerance``
times the emitted power ``Φ_E``. Then, exactly up to rounding (with the F the solver used):

* ``L = E + ρ F (L − ΔL)``: the residual of the radiosity equation is ``ρ_j Σ_i F_ji ΔL_i`` per patch,
  whose power ``Σ_j s_j π A_j |r_j|`` is at most ``ρ_max · U ≤ ρ_max · tolerance · Φ_E``;
* energy balance: ``Φ_E = absorbed + escaped + absorbed by back faces + U``;
* in a closed scene of uniform ρ, the total power ``Σ s π A L`` equals ``Φ_E / (1 − ρ) − ρ U / (1 − ρ)``:
  its relative deficit from Φ_E / (1 − ρ) is ``ρ U / Φ_E ≤ ρ · tolerance``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..core import Cancelled, Scene, form_factors
from .quadrature import PatchQuadrature, patch_quadrature

__all__ = ["FirstPassResult", "ProgressiveSolver", "SolveProgress", "make_solver", "shooter_form_factors",
           "solve_radiosity"]

#: default stopping tolerance: unshot power at most this fraction of the emitted power
DEFAULT_TOLERANCE = 1e-3
#: a step shoots every patch with at least this fraction of the largest unshot power (up to max_points)
BATCH_FRACTION = 0.25


@dataclass
class SolveProgress:
    """What a progress callback receives after every step."""

    shots: int
    steps: int
    unshot_fraction: float
    tolerance: float
    elapsed: float
    eta: float  # seconds, extrapolated from the logarithmic progress so far (nan before the first step)

    @property
    def fraction_done(self) -> float:
        """log(unshot) / log(tolerance), in [0, 1]: the convergence is roughly geometric."""
        u = max(self.unshot_fraction, 1e-300)
        if u <= self.tolerance or self.tolerance >= 1:
            return 1.0
        return float(min(1.0, max(0.0, np.log(u) / np.log(self.tolerance))))

    def message(self) -> str:
        eta = f"{self.eta:.0f} s" if np.isfinite(self.eta) else "?"
        return (f"first pass: {100 * self.fraction_done:5.1f}% shot {self.shots} patches in {self.steps} steps, "
                f"unshot {self.unshot_fraction:.2e} of emitted (target {self.tolerance:.0e}), "
                f"{self.elapsed:.1f} s, ETA {eta}")


@dataclass
class FirstPassResult:
    """The solution and its report. Powers are ``(3,)`` RGB in W (radiance × area × π)."""

    radiance: np.ndarray            # (n, 3) W sr^-1 m^-2, L = E + ρ Σ F L (up to the unshot part)
    unshot: np.ndarray              # (n, 3) unshot radiance ΔL left
    areas: np.ndarray               # (n,) m²
    sides: np.ndarray               # (n,) 1 or 2 (double-sided)
    shots: int
    steps: int
    converged: bool
    tolerance: float
    unshot_fraction: float
    emitted_power: np.ndarray
    absorbed_power: np.ndarray
    escaped_power: np.ndarray
    back_face_power: np.ndarray
    unshot_power: np.ndarray
    quadrature_error: float         # estimated fraction of the shot power sent to the wrong patches (nan: off)
    point_evaluations: int
    seconds: float
    order: int
    dropped: dict = field(default_factory=dict)
    clusters: int = 0               # shooting clusters of reflected light (0: every patch shoots; .clustered)
    cluster_shots: int = 0
    cluster_error: float = float("nan")  # estimated fraction of the clusters' power misdirected (4-point rule)

    @property
    def total_power(self) -> np.ndarray:
        """(3,) emitted plus reflected power ``Σ s π A L``."""
        return np.pi * (self.sides * self.areas) @ self.radiance

    @property
    def balance_error(self) -> float:
        """``|Φ_E − absorbed − escaped − back faces − unshot| / Φ_E`` (summed over RGB): rounding only."""
        e = float(self.emitted_power.sum())
        rest = self.absorbed_power + self.escaped_power + self.back_face_power + self.unshot_power
        return abs(e - float(rest.sum())) / e if e > 0 else 0.0

    def summary(self) -> str:
        e = max(float(self.emitted_power.sum()), 1e-300)
        q = "" if not np.isfinite(self.quadrature_error) else f", quadrature error est. {self.quadrature_error:.1e}"
        state = "converged" if self.converged else "NOT converged"
        if self.clusters:
            ce = f", est. {self.cluster_error:.1e}" if np.isfinite(self.cluster_error) else ""
            q += (f"; reflected light shot from {self.clusters} clusters ({self.cluster_shots} of the shots{ce}), "
                  "emitted light from the patches")
        return (f"first pass {state}: {len(self.areas)} patches, {self.shots} shots in {self.steps} steps, "
                f"unshot {self.unshot_fraction:.2e} of emitted (tolerance {self.tolerance:.0e}); energy: "
                f"absorbed {self.absorbed_power.sum() / e:.4f}, escaped {self.escaped_power.sum() / e:.4f}, "
                f"back faces {self.back_face_power.sum() / e:.4f}, unshot {self.unshot_power.sum() / e:.4f} "
                f"(balance error {self.balance_error:.1e}){q}; {self.point_evaluations} point evaluations, "
                f"{self.seconds:.1f} s")


def _as_rgb(values, n: int, what: str, scene: Scene) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full((n, 3), float(arr))
    elif arr.shape == (3,) and n != 3:
        arr = np.broadcast_to(arr, (n, 3)).copy()
    elif arr.shape == (n,):
        arr = np.repeat(arr[:, None], 3, axis=1)
    if arr.shape != (n, 3):
        raise ValueError(f"{what} must have shape ({n}, 3) or ({n},), got {arr.shape}")
    bad = np.flatnonzero(~np.isfinite(arr).all(axis=1))
    if len(bad):
        raise ValueError(f"{scene.describe(int(bad[0]))}: {what} is not finite ({arr[bad[0]].tolist()})")
    return arr


class ProgressiveSolver:
    """Progressive refinement on a core ``scene`` (its input polygons are the patches), one step at a time.

    Args:
        scene: core Scene (its radiance is ignored; polygons are opaque from both sides).
        reflectivity: (n, 3), (n,), (3,) or scalar diffuse reflectivity ρ in [0, 1].
        emission: the same shapes, emitted radiance E (W sr^-1 m^-2) of the front side (both sides when
            ``double_sided``).
        tolerance: stop when the unshot power is at most this fraction of the emitted power.
        order: quadrature rule on the shooters (:mod:`.quadrature`): 2 (default) or 1.
        double_sided: patches emit, receive and reflect on both sides (default: ``scene.double_sided``).
        max_points: quadrature points per step (several shooters are shot together; memory O(max_points × n)).
        max_shots: give up (``converged=False``) after this many shots (default 200 n + 1000).
        estimate_error: also evaluate the 1-point rule at every shooter (one more point per piece) and
            report half the L1 difference of the distributed power as the quadrature error estimate.
    """

    def __init__(self, scene: Scene, reflectivity, emission, *, tolerance: float = DEFAULT_TOLERANCE, order: int = 2,
                 double_sided: bool | None = None, max_points: int | None = None, max_shots: int | None = None,
                 estimate_error: bool = True):
        if not (0.0 <= tolerance < 1.0):
            raise ValueError(f"tolerance must lie in [0, 1), got {tolerance}")
        n = scene.n_input
        self.scene = scene
        self.rho = _as_rgb(reflectivity, n, "reflectivity", scene)
        self.emit = _as_rgb(emission, n, "emission", scene)
        bad = np.flatnonzero(((self.rho < 0) | (self.rho > 1)).any(axis=1))
        if len(bad):
            raise ValueError(f"{scene.describe(int(bad[0]))}: reflectivity {self.rho[bad[0]].tolist()} is outside "
                             "[0, 1] (a diffuse surface cannot reflect more than it receives)")
        bad = np.flatnonzero((self.emit < 0).any(axis=1))
        if len(bad):
            raise ValueError(f"{scene.describe(int(bad[0]))}: emission {self.emit[bad[0]].tolist()} is negative")
        self.tolerance = float(tolerance)
        self.order = order
        self.double_sided = scene.double_sided if double_sided is None else bool(double_sided)
        self.quad = patch_quadrature(scene, order)
        self.check = patch_quadrature(scene, 1) if estimate_error and order != 1 else None
        self.sides = np.full(n, 2.0 if self.double_sided else 1.0)
        self.max_points = max_points or int(np.clip(2**21 // max(n, 1), 8, 96))
        self.max_shots = 200 * n + 1000 if max_shots is None else int(max_shots)
        # receiving side: the plane of every patch's first convex piece
        first = np.searchsorted(scene.poly_source, np.arange(n))
        present = np.zeros(n, dtype=bool)
        present[scene.poly_source] = True
        first = np.minimum(first, max(scene.n_polygons - 1, 0))
        self._rx_normal = np.where(present[:, None], scene.poly_normals[first] if scene.n_polygons else 0.0, 0.0)
        self._rx_offset = np.where(present, scene.poly_offsets[first] if scene.n_polygons else 0.0, 0.0)
        self.radiance = self.emit.copy()
        self.unshot = self.emit.copy()
        self.unshot[self.quad.areas <= 0] = 0.0  # dropped polygons have no area: nothing to shoot
        self._power_scale = np.pi * self.sides * self.quad.areas            # (n,) W per unit radiance
        self.emitted_power = self._power_scale @ self.emit
        self.absorbed = np.zeros(3)
        self.escaped = np.zeros(3)
        self.back = np.zeros(3)
        self.shots = 0
        self.steps = 0
        self.point_evaluations = 0
        self._misdirected = 0.0
        self._shot_power = 0.0
        self._start = time.perf_counter()
        self._elapsed = 0.0

    # ------------------------------------------------------------------ state
    def unshot_power(self) -> np.ndarray:
        """(3,) W."""
        return self._power_scale @ self.unshot

    @property
    def unshot_fraction(self) -> float:
        e = float(self.emitted_power.sum())
        return float(self.unshot_power().sum()) / e if e > 0 else 0.0

    @property
    def converged(self) -> bool:
        return self.unshot_fraction <= self.tolerance

    @property
    def done(self) -> bool:
        return self.converged or self.shots >= self.max_shots

    def progress(self) -> SolveProgress:
        p = SolveProgress(self.shots, self.steps, self.unshot_fraction, self.tolerance, self._elapsed, float("nan"))
        f = p.fraction_done
        if 0 < f < 1:
            p.eta = self._elapsed * (1 - f) / f
        elif f >= 1:
            p.eta = 0.0
        return p

    # ------------------------------------------------------------------ one step
    def _shooters(self) -> np.ndarray:
        u = self._power_scale * self.unshot.sum(axis=1)                       # (n,) W
        top = float(u.max()) if len(u) else 0.0
        if top <= 0:
            return np.zeros(0, dtype=np.int64)
        cand = np.flatnonzero(u >= BATCH_FRACTION * top)
        cand = cand[np.argsort(-u[cand], kind="stable")]
        npts = (self.quad.start[cand + 1] - self.quad.start[cand]) * (2 if self.double_sided else 1)
        keep = max(1, int(np.searchsorted(np.cumsum(npts), self.max_points, side="right")))
        return np.sort(cand[:keep])

    def _factors(self, pts: np.ndarray, nrm: np.ndarray, power: np.ndarray):
        """Exact factors ``(q', n)`` from shooting points ``pts (q, 3)`` with normals ``nrm`` and per-side power
        ``power (q, 3)`` (W); both sides when double-sided (q' = 2q). Returns ``(f, front, power)``."""
        if self.double_sided:
            pts, nrm, power = np.concatenate([pts, pts]), np.concatenate([nrm, -nrm]), np.concatenate([power, power])
        f = form_factors(self.scene, pts, nrm)                                # (q, n) exact, occluded
        self.point_evaluations += len(pts)
        front = None
        if not self.double_sided:
            front = (pts @ self._rx_normal.T - self._rx_offset) > 0           # (q, n) lit on its front side
        return f, front, power

    def _distribute(self, quad: PatchQuadrature, shooters: np.ndarray, shot: np.ndarray):
        """Power received by every patch ``(n, 3)`` front/back-wise from shooters' unshot radiance ``shot``."""
        idx = quad.of(shooters)
        pts, nrm, w = quad.points[idx], quad.normals[idx], quad.weights[idx]
        owner = np.searchsorted(shooters, quad.patch[idx])                    # (q,) row of shot
        power = np.pi * w[:, None] * shot[owner]                              # (q, 3) W per side
        return self._factors(pts, nrm, power)

    def _receive(self, f: np.ndarray, front, power: np.ndarray) -> np.ndarray:
        """Book the power ``power (q, 3)`` shot along ``f (q, n)``: escaped, back faces, absorbed, and the
        reflected part added to the radiance and to the unshot radiance. Returns the received ``(n, 3)`` W."""
        sent = power.sum(axis=0)                                              # (3,)
        seen = f.sum(axis=1)                                                  # (q,)
        self.escaped += (1.0 - np.minimum(seen, 1.0)) @ power
        if front is not None:
            fr = np.where(front, f, 0.0)
            received = fr.T @ power                                           # (n, 3)
            self.back += sent - (1.0 - np.minimum(seen, 1.0)) @ power - received.sum(axis=0)
        else:
            received = f.T @ power
        reflected = self.rho * received
        self.absorbed += (received - reflected).sum(axis=0)
        area = self._power_scale
        gain = np.divide(reflected, area[:, None], out=np.zeros_like(reflected), where=area[:, None] > 0)
        self.radiance += gain
        self.unshot += gain
        self._shot_power += float(sent.sum())
        return received

    def step(self) -> int:
        """Shoot one batch of patches; returns how many were shot (0 when nothing is left)."""
        t0 = time.perf_counter()
        shooters = self._shooters()
        if not len(shooters):
            return 0
        shot = self.unshot[shooters].copy()                                   # (s, 3)
        self.unshot[shooters] = 0.0
        self._shoot_patches(shooters, shot)
        self.shots += len(shooters)
        self.steps += 1
        self._elapsed += time.perf_counter() - t0
        return len(shooters)

    def _shoot_patches(self, shooters: np.ndarray, shot: np.ndarray):
        """Shoot the unshot radiance ``shot (s, 3)`` of the patches ``shooters`` with the patch rule."""
        f, front, power = self._distribute(self.quad, shooters, shot)
        received = self._receive(f, front, power)
        if self.check is not None:
            f1, front1, power1 = self._distribute(self.check, shooters, shot)
            rec1 = (np.where(front1, f1, 0.0) if front1 is not None else f1).T @ power1
            self._misdirected += 0.5 * float(np.abs(received - rec1).sum())

    def result(self) -> FirstPassResult:
        q = self._misdirected / self._shot_power if self.check is not None and self._shot_power > 0 else (
            0.0 if self.check is not None else float("nan"))
        return FirstPassResult(
            radiance=self.radiance.copy(), unshot=self.unshot.copy(), areas=self.quad.areas.copy(),
            sides=self.sides.copy(), shots=self.shots, steps=self.steps, converged=self.converged,
            tolerance=self.tolerance, unshot_fraction=self.unshot_fraction, emitted_power=self.emitted_power.copy(),
            absorbed_power=self.absorbed.copy(), escaped_power=self.escaped.copy(), back_face_power=self.back.copy(),
            unshot_power=self.unshot_power(), quadrature_error=q, point_evaluations=self.point_evaluations,
            seconds=self._elapsed, order=self.order, dropped=dict(self.scene.dropped))

    def run(self, progress: Callable[[SolveProgress], None] | None = None,
            cancel: Callable[[], bool] | None = None) -> FirstPassResult:
        """Step until converged (or ``max_shots``); ``progress(SolveProgress)`` after every step;
        ``cancel()`` returning True raises :class:`~hemisphere_local_pass.core.Cancelled`."""
        while not self.done:
            if cancel is not None and cancel():
                raise Cancelled(f"first pass cancelled after {self.shots} shots "
                                f"(unshot {self.unshot_fraction:.2e} of emitted)")
            if not self.step():
                break
            if progress is not None:
                progress(self.progress())
        return self.result()


def make_solver(scene: Scene, reflectivity, emission, *, clusters: int | None = None, **kwargs) -> ProgressiveSolver:
    """:class:`ProgressiveSolver`, or with ``clusters`` (> 0) the :class:`~.clustered.ClusteredSolver` that shoots
    reflected light from about that many clusters of patches (large scenes: docs/first-pass.md)."""
    if clusters:
        from .clustered import ClusteredSolver

        return ClusteredSolver(scene, reflectivity, emission, clusters=int(clusters), **kwargs)
    return ProgressiveSolver(scene, reflectivity, emission, **kwargs)


def solve_radiosity(scene: Scene, reflectivity, emission, *, progress=None, cancel=None, **kwargs) -> FirstPassResult:
    """Solve diffuse radiosity on ``scene``'s input polygons (see :class:`ProgressiveSolver` for the
    arguments, and ``clusters`` in :func:`make_solver`); returns :class:`FirstPassResult` (``.radiance (n, 3)``,
    the report in ``.summary()``)."""
    return make_solver(scene, reflectivity, emission, **kwargs).run(progress=progress, cancel=cancel)


def shooter_form_factors(scene: Scene, shooter: int, *, order: int = 2, double_sided: bool | None = None,
                         quadrature: PatchQuadrature | None = None) -> np.ndarray:
    """The row ``F_i· (n,)`` the solver uses for ``shooter`` i: power fractions reaching each patch (front sides
    only unless double-sided; for a double-sided shooter the mean over its two sides). For checks."""
    ds = scene.double_sided if double_sided is None else bool(double_sided)
    quad = quadrature if quadrature is not None else patch_quadrature(scene, order)
    idx = quad.of(np.array([shooter]))
    pts, nrm, w = quad.points[idx], quad.normals[idx], quad.weights[idx]
    if ds:
        pts, nrm, w = np.concatenate([pts, pts]), np.concatenate([nrm, -nrm]), np.concatenate([w, w]) / 2
    f = form_factors(scene, pts, nrm)
    if not ds:
        n = scene.n_input
        first = np.minimum(np.searchsorted(scene.poly_source, np.arange(n)), scene.n_polygons - 1)
        present = np.zeros(n, dtype=bool)
        present[scene.poly_source] = True
        side = pts @ scene.poly_normals[first].T - scene.poly_offsets[first]
        f = np.where((side > 0) & present[None, :], f, 0.0)
    area = quad.areas[shooter]
    return (w @ f) / area if area > 0 else np.zeros(scene.n_input)
