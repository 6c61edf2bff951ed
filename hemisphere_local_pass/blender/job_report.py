"""What a local-pass job reports: :class:`JobReport` at its end, a :class:`JobStep` after every
chunk, and on the way its progress (``progress(done, total)``) and stages (``status(text)``).

Written for Python 3.10+ (Debian's Blender 3.4): no newer syntax.
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["JobReport", "JobStep", "Reporter", "stage"]


@dataclass
class JobReport:
    """What a local-pass job did.

    Attributes:
        mode: "pixels" or "vertices".
        points: receiver points evaluated (hit samples, or vertices/corners).
        seconds: wall-clock time of the whole job.
        max_form_factor_error: max |sum F - 1| over the receivers (0 in a closed scene up to rounding;
            large where a receiver sees the open sky).
        black_occluders: objects without the radiosity attribute exported as black occluders.
        dropped_polygons: degenerate polygons the core dropped ("Object.polygon i: reason").
        outputs: files written (EXR, PNG) and attributes written ("Object:hlp_radiance").
        refused: files not written, each a message naming the path and why (an existing PNG preview
            that is not ours, or that may not be overwritten); see :mod:`.output_paths`.
        image_size, window: pixels mode: (W, H) and the computed (x0, y0, x1, y1).
        resumed_points: receivers taken from a checkpoint instead of being computed.
        cancelled: the job stopped early (finished chunks are in the checkpoint).
        workers: worker processes the receivers were computed on (1: this process only).
        objects: names of the exported objects; the EXR's ``object_index`` indexes this list.
        result: the float64 results: pixels mode the image layers of the window (see
            :mod:`.outputs`; row 0 at the bottom); vertices mode ``{object name: (domain, radiance,
            irradiance, computed mask)}``.
    """

    mode: str
    points: int = 0
    seconds: float = 0.0
    max_form_factor_error: float = 0.0
    black_occluders: list = field(default_factory=list)
    dropped_polygons: list = field(default_factory=list)
    outputs: list = field(default_factory=list)
    refused: list = field(default_factory=list)
    image_size: tuple | None = None
    window: tuple | None = None
    resumed_points: int = 0
    cancelled: bool = False
    workers: int = 1
    objects: list = field(default_factory=list, repr=False)
    result: dict = field(default_factory=dict, repr=False)
    exact_points: int | None = None       # adaptive pass: exact evaluations (None: every point exact)
    tolerance: float | None = None        # adaptive pass / far field: the absolute tolerance on H used
    error_estimate: float | None = None   # adaptive pass: largest per-pixel error estimate of H;
    #                                       vertices' far field: largest error bound of H

    @property
    def points_per_second(self) -> float:
        computed = self.points - self.resumed_points
        return computed / self.seconds if self.seconds > 0 else 0.0

    def summary(self) -> str:
        """One line for the UI and the command line."""
        parts = [f"{self.points} points in {self.seconds:.1f} s ({self.points_per_second:.0f} points/s)"]
        if self.exact_points is None and self.tolerance is not None:
            parts.append(f"far field: error bound <= {self.error_estimate:.2e} (tolerance {self.tolerance:.2e} W/m2)")
        elif self.exact_points is None:
            parts.append(f"max |sum F - 1| = {self.max_form_factor_error:.2e}")
        else:
            parts.append(f"adaptive: {self.exact_points} exact, estimated error <= {self.error_estimate:.2e} "
                         f"(tolerance {self.tolerance:.2e} W/m2)")
        if self.black_occluders:
            parts.append(f"{len(self.black_occluders)} black occluder(s)")
        if self.dropped_polygons:
            parts.append(f"{len(self.dropped_polygons)} degenerate polygon(s) dropped")
        if self.workers > 1:
            parts.append(f"{self.workers} workers")
        return "Local pass: " + ", ".join(parts)


@dataclass
class JobStep:
    """What :func:`.pipeline.local_pass_steps` yields after every finished chunk (and, while the
    adaptive pass runs, every ``adaptive_pixels.POLL_SECONDS``): ``done`` of ``total`` receivers
    (points) evaluated so far. Between two steps nothing of Blender's data is touched, so a modal
    operator can return to the event loop there (``blender/modal.py``)."""

    done: int
    total: int


class Reporter:
    """The job's ``progress(done, total)`` for the receivers plus ``stage(text)`` for the steps before
    them (export, ray casting, preparation), which take a minute on a 200,000-polygon scene; either
    callback may be None. ``stage(None)``: the job is over."""

    def __init__(self, progress, status):
        self.progress = progress
        self.status = status

    def __call__(self, done, total):
        if self.progress is not None:
            self.progress(done, total)

    def stage(self, text):
        if self.status is not None:
            self.status(text)


def stage(progress, text):
    """Tell the job's status callback (if any) that a stage begins: ``text`` (None: the job is over)."""
    stage = getattr(progress, "stage", None)
    if stage is not None:
        stage(text)
