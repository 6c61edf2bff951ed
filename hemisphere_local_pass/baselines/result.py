"""The common result of the baseline methods."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["BaselineResult"]


class BaselineResult(NamedTuple):
    """Estimates at ``m`` receivers.

    Attributes:
        form_factors: (m, n_input) float64 form factor of every input polygon (geometric: both sides).
        irradiance: (m, 3) float64 irradiance ``H = π Σ_i L_i F_i`` (W m^-2, eq. 1; the core's
            :func:`~..core.irradiance` convention) with radiance ``L_i``, polygons lit on their front side
            only unless the scene is double sided.
        stderr: (m, 3) float64 standard error of ``irradiance`` (Monte Carlo), or None.
    """

    form_factors: np.ndarray
    irradiance: np.ndarray
    stderr: np.ndarray | None
