"""The job's public names, where the README, docs/, scripts and Blender 3.4's batch form
(``from hemisphere_local_pass.blender import job; sys.exit(job.cli_main([...]))``) import them from.

Nothing is computed here; the names live in the modules that do the work::

    pipeline.py          run_local_pass, local_pass_steps: the one job function (settings, export, mode)
    job_report.py        JobReport (what a job did), JobStep (one per chunk), progress and stages
    pixels_pass.py       pixels mode: camera rays -> receivers -> H -> eq. 5 -> EXR / PNG / image
    adaptive_pixels.py   pixels mode's adaptive pass (tolerance > 0), one JobStep per progress poll
    vertices_pass.py     vertices mode: receivers -> H -> eq. 5 -> colour attributes
    vertex_receivers.py  vertices mode's receivers: points, normals, limit directions, rho and E
    receiver_chunks.py   receivers in fixed chunks (MIN_CHUNK ...), checkpointed, a JobStep per chunk
    chunk_evaluation.py  one chunk through the core: H and sum F; the scene's preparation stage
    worker_chunks.py     the chunks on worker processes
    checkpoint.py        <output>.checkpoint.npz: finished chunks, the job's fingerprint
    tiles.py             --tile I/N: row bands of the pixel window
    cli.py               the command line: handler (blender -c), build_parser, cli_main
    stderr_lines.py      the commands' stderr: progress lines, error_line
    blend_output.py      the .blend a command saves to (checked, atomic, .blend1 kept)

The layers (no import cycle, tests/core/test_imports.py): job -> cli -> pipeline -> pixels_pass,
vertices_pass -> receiver_chunks -> worker_chunks, chunk_evaluation, checkpoint -> job_report.
"""

from __future__ import annotations

from .cli import build_parser, cli_main, error_line
from .job_report import JobReport, JobStep
from .pipeline import local_pass_steps, run_local_pass
from .pixels_pass import IMAGE_NAME
from .tiles import parse_tile, tile_window

__all__ = ["IMAGE_NAME", "JobReport", "JobStep", "build_parser", "cli_main", "error_line", "local_pass_steps",
           "parse_tile", "run_local_pass", "tile_window"]
