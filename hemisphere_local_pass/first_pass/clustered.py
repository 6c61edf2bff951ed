"""Progressive refinement for large scenes: emitted light shot from the elements, reflected light from clusters.

The flat solver (:class:`.progressive.ProgressiveSolver`) needs a few sweeps of n shots, each an exact point
evaluation against all n polygons: time ~n² (days at 10⁵ polygons here). Substructuring (Cohen, Greenberg,
Immel & Brock 1986) keeps the polygons as the *elements* that receive light and carry the solution, but
shoots the light they reflect from about ``clusters`` groups of them (:mod:`.clusters`), one exact point
evaluation per cluster shot: time ~(sweeps × clusters) point evaluations of O(n) each, memory O(n).

Every element keeps two unshot radiances: emitted ``ΔL^E`` (initially E) and reflected ``ΔL^R``
(initially 0; it collects what the element reflects). A step shoots either

* emitted light of the elements with the most unshot emitted power, each with its own patch rule
  (:mod:`.quadrature`, ``order``) — direct light, and the shadows it casts, are resolved on the elements; or,
  once all emission is shot,
* the reflected light of the clusters with the most unshot reflected power (within 25 % of the largest,
  up to ``max_points`` per step): cluster c shoots ``ΔΦ_c = Σ_{i∈c} s_i π A_i ΔL^R_i`` from its point
  ``x_c``; element j receives ``ΔΦ_c F(x_c → j)`` (exact, occluded) and reflects ρ_j of it into its
  radiance and its ``ΔL^R``.

**What the solution satisfies**, exactly up to rounding: with the fixed operators the solver used —
``F^E_ij`` (element i's patch rule) for emitted light and ``C_cj = F(x_c → j)`` for reflected light —

    L_j = E_j + ρ_j / (s_j π A_j) · [ Σ_i F^E_ij s_i π A_i (E_i − ΔL^E_i)
                                     + Σ_c C_cj Σ_{i∈c} s_i π A_i (L_i − E_i − ΔL^R_i) ]

(``tests/core/test_first_pass_clustered.py`` rebuilds both and checks it to 1e-12), and the stopping
criterion, energy balance and closed-box identity of :mod:`.progressive` hold unchanged (a cluster's point
lies strictly inside an element: the factors of a closed scene sum to 1). The approximation is the
one-point rule per cluster on reflected light (:mod:`.clusters`: relative O(h/r) at distance r from a
cluster of size h, O(1) within about h of its point); the solver estimates it on every
``estimate_every``-th step's first cluster with a 4-point quadrant rule (half the L1 difference of the
distributed power, as a fraction of that cluster's power) and reports the mean, weighted by power.
"""

from __future__ import annotations

import time

import numpy as np

from .clusters import make_clusters, quadrant_points
from .progressive import BATCH_FRACTION, DEFAULT_TOLERANCE, FirstPassResult, ProgressiveSolver
from .quadrature import patch_quadrature

__all__ = ["ClusteredSolver"]


class ClusteredSolver(ProgressiveSolver):
    """:class:`ProgressiveSolver` whose reflected light is shot from about ``clusters`` clusters of patches.

    Args (beyond :class:`ProgressiveSolver`'s):
        clusters: about how many shooting clusters (>= 1; the count depends on the geometry, see
            :func:`.clusters.make_clusters`).
        estimate_every: the 4-point estimate of the cluster rule's error on every so many cluster steps
            (0: off). ``estimate_error`` (the patch rule's estimate on the emission shots) as before.
    """

    def __init__(self, scene, reflectivity, emission, *, clusters: int, tolerance: float = DEFAULT_TOLERANCE,
                 order: int = 2, estimate_every: int = 4, **kwargs):
        super().__init__(scene, reflectivity, emission, tolerance=tolerance, order=order, **kwargs)
        if int(clusters) < 1:
            raise ValueError(f"clusters must be at least 1, got {clusters}")
        self.quad1 = self.quad if order == 1 else patch_quadrature(scene, 1)
        self.target_clusters = int(clusters)
        self.clusters = make_clusters(self.quad1, self.rho, self.emit, self.target_clusters, scene=scene)
        self._placed = False                                                   # points fixed after the direct light
        self.unshot_emitted = self.unshot.copy()                               # ΔL^E (n, 3); ΔL^R = unshot − ΔL^E
        self.estimate_every = int(estimate_every)
        self.cluster_shots = 0
        self.cluster_steps = 0
        self._cluster_misdirected = 0.0
        self._cluster_sampled = 0.0
        self._cluster_power = 0.0
        self._emission_power = 0.0

    # ------------------------------------------------------------------ one step
    def step(self) -> int:
        t0 = time.perf_counter()
        shot_now = self._step_emission() or self._step_clusters()
        if shot_now:
            self.steps += 1
        self._elapsed += time.perf_counter() - t0
        return shot_now

    def _step_emission(self) -> int:
        u = self._power_scale * self.unshot_emitted.sum(axis=1)
        top = float(u.max()) if len(u) else 0.0
        if top <= 0:
            return 0
        cand = np.flatnonzero(u >= BATCH_FRACTION * top)
        cand = cand[np.argsort(-u[cand], kind="stable")]
        npts = (self.quad.start[cand + 1] - self.quad.start[cand]) * (2 if self.double_sided else 1)
        keep = max(1, int(np.searchsorted(np.cumsum(npts), self.max_points, side="right")))
        shooters = np.sort(cand[:keep])
        shot = self.unshot_emitted[shooters].copy()
        self.unshot_emitted[shooters] = 0.0
        self.unshot[shooters] -= shot
        before = self._shot_power
        self._shoot_patches(shooters, shot)
        self._emission_power += self._shot_power - before
        self.shots += len(shooters)
        return len(shooters)

    def _reflected_power(self) -> np.ndarray:
        """(count, 3) W: the unshot reflected power of every cluster."""
        cl = self.clusters
        el = cl.members
        p = self._power_scale[el, None] * (self.unshot[el] - self.unshot_emitted[el])
        out = np.zeros((cl.count, 3))
        for c in range(3):
            out[:, c] = np.bincount(cl.of[el], weights=p[:, c], minlength=cl.count)
        return out

    def _step_clusters(self) -> int:
        if not self._placed:  # all emission is shot: place the points where the reflected power is
            held = self._power_scale * (self.unshot - self.unshot_emitted).sum(axis=1)
            self.clusters = make_clusters(self.quad1, self.rho, self.emit, self.target_clusters, weights=held,
                                          scene=self.scene)
            self._placed = True
        cl = self.clusters
        pc = self._reflected_power()                                          # (count, 3)
        u = pc.sum(axis=1)
        top = float(u.max()) if len(u) else 0.0
        if top <= 0:
            return 0
        cand = np.flatnonzero(u >= BATCH_FRACTION * top)
        cand = cand[np.argsort(-u[cand], kind="stable")]
        per = 2 if self.double_sided else 1
        chosen = np.sort(cand[:max(1, self.max_points // per)])
        sample = self.estimate_every > 0 and self.cluster_steps % self.estimate_every == 0
        if sample:
            c0 = int(cand[0])
            reflected = self._power_scale[:, None] * (self.unshot - self.unshot_emitted)
            q_pts, q_nrm, q_pow = quadrant_points(cl, self.quad1, c0, reflected)
        mask = np.isin(cl.of, chosen)
        self.unshot[mask] = self.unshot_emitted[mask]                         # their ΔL^R is shot
        power = pc[chosen] / per                                              # (q, 3) W per side
        f, front, power = self._factors(cl.point[chosen], cl.normal[chosen], power)
        self._receive(f, front, power)
        shot = float(pc[chosen].sum())
        self._cluster_power += shot
        if sample:
            row = int(np.searchsorted(chosen, c0))
            rows = [row, row + len(chosen)] if self.double_sided else [row]
            ff = f[rows] if front is None else np.where(front[rows], f[rows], 0.0)
            rec1 = ff.T @ power[rows]
            f4, front4, p4 = self._factors(q_pts, q_nrm, q_pow / per)
            rec4 = (f4 if front4 is None else np.where(front4, f4, 0.0)).T @ p4
            self._cluster_misdirected += 0.5 * float(np.abs(rec1 - rec4).sum())
            self._cluster_sampled += float(pc[c0].sum())
        self.shots += len(chosen)
        self.cluster_shots += len(chosen)
        self.cluster_steps += 1
        return len(chosen)

    # ------------------------------------------------------------------ report
    @property
    def cluster_error(self) -> float:
        """Estimated fraction of the clusters' shot power sent to other elements than a 4-point rule would."""
        return self._cluster_misdirected / self._cluster_sampled if self._cluster_sampled > 0 else float("nan")

    def result(self) -> FirstPassResult:
        r = super().result()
        ce = self.cluster_error
        # the patch rule's estimate covers the emission shots; the clusters' the rest (power-weighted)
        if self._shot_power > 0:
            parts = []
            if self.check is not None:
                parts.append(self._misdirected)
            if np.isfinite(ce):
                parts.append(ce * self._cluster_power)
            r.quadrature_error = sum(parts) / self._shot_power if parts else float("nan")
        r.clusters = self.clusters.count
        r.cluster_shots = self.cluster_shots
        r.cluster_error = ce
        return r

    def cluster_form_factors(self, c: int) -> np.ndarray:
        """The row ``C_c· (n,)`` the solver uses for cluster ``c``: fractions of its shot power reaching each
        element (front sides only unless double-sided; the mean over both sides when double-sided). For checks."""
        cl = self.clusters
        pts, nrm = cl.point[c:c + 1], cl.normal[c:c + 1]
        per = 2 if self.double_sided else 1
        f, front, w = self._factors(pts, nrm, np.full((1, 3), 1.0 / per))
        self.point_evaluations -= len(f)
        if front is not None:
            f = np.where(front, f, 0.0)
        return w[:, 0] @ f
