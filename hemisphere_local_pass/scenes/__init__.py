"""Procedural test and sample scenes (pure numpy); ``radiosity()`` wraps the first pass (``..first_pass``)."""

from .cornell_box import PAPER_SETTINGS, CornellBox, camera_rays, cornell_box
from .radiosity import centroid_form_factors, gathered_radiance, radiosity
from .uv_sphere import uv_sphere

__all__ = ["PAPER_SETTINGS", "CornellBox", "camera_rays", "centroid_form_factors", "cornell_box",
           "gathered_radiance", "radiosity", "uv_sphere"]
