"""Baseline local-pass methods, for comparison with the exact projection (pure numpy).

* :func:`hemicube` — Cohen & Greenberg 1985, item-buffer z-buffer on five faces, randomly rotated.
* :func:`raytraced_form_factors` — Wallace, Elmquist & Haines 1989 with eq. 4 for the unoccluded factor.
* :func:`monte_carlo` — cosine-weighted hemisphere sampling with a standard error.
* :func:`unoccluded_form_factors` — eq. 4 for every polygon, no visibility (the cost floor).

All return :class:`BaselineResult` (``form_factors (m, n_input)``, ``irradiance (m, 3)``, ``stderr``).
"""

from .analytic import unoccluded_form_factors
from .hemicube import delta_form_factors, hemicube
from .monte_carlo import monte_carlo
from .raytraced_ff import raytraced_form_factors
from .result import BaselineResult

__all__ = ["BaselineResult", "delta_form_factors", "hemicube", "monte_carlo", "raytraced_form_factors",
           "unoccluded_form_factors"]
