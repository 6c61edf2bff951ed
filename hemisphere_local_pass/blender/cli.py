"""``blender -b [scene.blend] -c hemisphere_local_pass render|merge|solve ...``: the command-line entry point.

Registered with ``bpy.utils.register_cli_command`` (Blender 4.2+) by ``registration.register()``.
:func:`handler` is an argparse program that makes no UI calls and returns the process exit code;
:func:`cli_main` runs the sub-commands (``render``, ``merge``; ``solve`` is ``first_pass.cli_main``),
one short call into the job function (:func:`.pipeline.run_local_pass`). Under Blender 3.4, which has
no ``--command``, the same program runs as ``blender -b scene.blend --python-exit-code 1
--python-expr "...; from hemisphere_local_pass.blender import job; sys.exit(job.cli_main([...]))"``
(both parts are needed for a non-zero exit on errors; docs/blender.md; ``job`` re-exports
:func:`cli_main`).

Written for Python 3.10+ (Debian's Blender 3.4): no newer syntax.
"""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass

from .stderr_lines import StderrProgress, error_line, run_command

COMMAND = "hemisphere_local_pass"
SUBCOMMANDS = ("render", "merge", "solve")
PROG = f"blender --command {COMMAND}"

__all__ = ["COMMAND", "PROG", "build_parser", "cli_main", "error_line", "handler"]


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Exact local pass of two-pass global illumination for the loaded .blend file.",
        epilog=f"Run '{PROG} SUBCOMMAND --help' for the options of a sub-command.",
        add_help=False,
    )
    parser.add_argument("subcommand", nargs="?", choices=SUBCOMMANDS,
                        help="render, merge or solve (the first pass)")
    parser.add_argument("-h", "--help", action="store_true", help="show this help message and exit")
    parser.add_argument("--version", action="store_true", help="print the extension's version and exit")
    return parser


def _version() -> str:
    """The version in ``blender_manifest.toml`` (beside the installed package, or at the checkout's top)."""
    import os

    import tomllib  # Blender 4.2+ (Python 3.11+), the only Blenders with --command

    package_dir = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    for directory in (package_dir, os.path.dirname(package_dir)):
        path = os.path.join(directory, "blender_manifest.toml")
        if os.path.isfile(path):
            with open(path, "rb") as fh:
                return tomllib.load(fh)["version"]
    return "unknown"


def handler(argv: list[str]) -> int:
    """Run the command with ``argv`` (the arguments after ``-c hemisphere_local_pass``); return the exit code."""
    argv = list(argv)
    parser = _parser()
    if not argv or argv[0] in ("-h", "--help"):
        parser.print_help()
        return 0
    if argv[0] == "--version":
        print(f"{COMMAND} {_version()}")
        return 0
    if argv[0].startswith("-") or argv[0] not in SUBCOMMANDS:
        parser.print_usage(sys.stderr)
        print(f"{PROG}: error: expected a sub-command 'render', 'merge' or 'solve', got '{argv[0]}'", file=sys.stderr)
        return 2
    try:
        from . import pipeline  # noqa: F401  (the job function: numpy and the core)
    except ImportError as ex:  # a broken installation: one line, non-zero
        print(f"{PROG}: error: cannot load the job module: {ex}", file=sys.stderr)
        return 1
    try:
        return int(cli_main(argv) or 0)
    except SystemExit as ex:  # argparse inside the job (--help, bad options) exits; Blender must not
        code = ex.code
        return code if isinstance(code, int) else (0 if code is None else 1)
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130


def _region(values):
    if values is None:
        return None
    return tuple(int(v) for v in values)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Exact local pass of two-pass global illumination for the loaded .blend file.",
    )
    sub = parser.add_subparsers(dest="command", metavar="{render,merge,solve}")
    sub.required = True
    r = sub.add_parser("render", help="compute the local pass (pixels: EXR + PNG; vertices: colour attributes)")
    r.add_argument("--output", "-o", help="pixels: the OpenEXR file (a PNG preview goes next to it); "
                   "vertices: the .blend file to save with the colour attributes")
    r.add_argument("--mode", choices=("pixels", "vertices"), default=None)
    r.add_argument("--attribute", default=None, help="radiosity attribute (default: scene setting or 'radiosity')")
    r.add_argument("--region", nargs=4, type=int, metavar=("X0", "Y0", "X1", "Y1"),
                   help="pixel window, x from the left, y from the bottom, half-open")
    r.add_argument("--tile", metavar="I/N", help="compute row band I of N (1-based, from the top) as a partial EXR")
    r.add_argument("--resume", action="store_true", help="continue from OUTPUT.checkpoint.npz")
    r.add_argument("--samples", type=int, default=None, metavar="K", help="K x K rays per pixel")
    r.add_argument("--tolerance", type=float, default=None, metavar="REL",
                   help="error tolerance relative to the mean irradiance (e.g. 1e-3; 0 = exact; default: scene "
                   "setting or 0). Pixels: the adaptive pass (samples error-bounded, the rest interpolated); "
                   "vertices: the error-bounded far field, its bound in the attribute <irradiance attribute>_bound")
    r.add_argument("--missing", choices=("error", "black"), default=None,
                   help="objects without the attribute: error (default) or black occluders")
    r.add_argument("--no-preview", action="store_true", help="do not write the PNG preview")
    r.add_argument("--overwrite", action="store_true",
                   help="replace existing outputs this extension wrote (EXR, PNG, checkpoint; vertices: the .blend, "
                   "keeping the old one as .blend1); files it did not write are never replaced")
    r.add_argument("--objects", nargs="+", metavar="NAME",
                   help="vertices: the mesh objects to evaluate (default: the objects selected in the file)")
    r.add_argument("--radiance-attribute", metavar="NAME", help="vertices: radiance target (default hlp_radiance)")
    r.add_argument("--irradiance-attribute", metavar="NAME",
                   help="vertices: irradiance target (default hlp_irradiance)")
    r.add_argument("--workers", "-j", type=int, default=None, metavar="N",
                   help="worker processes (0: every core this process may use, the default; 1: none)")
    r.add_argument("--quiet", "-q", action="store_true", help="no progress lines")
    sub.add_parser("solve", add_help=False, help="first pass: solve radiosity and write the FACE-domain attribute "
                   "(options: solve --help; hemisphere_local_pass.blender.first_pass)")
    m = sub.add_parser("merge", help="assemble tile EXRs into one image (and its PNG preview)")
    m.add_argument("tiles", nargs="+", metavar="TILE_FILES")
    m.add_argument("--output", "-o", required=True)
    m.add_argument("--no-preview", action="store_true", help="do not write the PNG preview of the merged image")
    m.add_argument("--overwrite", action="store_true", help="replace an existing merged image this extension wrote")
    return parser


def cli_main(argv) -> int:
    """The ``blender --command hemisphere_local_pass`` program: returns the exit code; errors are
    one line on stderr (exit 1), Ctrl-C exits 130 after the finished chunks are saved."""
    if list(argv)[:1] == ["solve"]:  # the first pass: its own program (blender/first_pass.py)
        from .first_pass import cli_main as solve_main

        return solve_main(list(argv)[1:])
    args = build_parser().parse_args(list(argv))
    if args.command == "merge":
        return run_command(lambda: _merge(args), cancelled="cancelled",  # files are replaced whole or not at all
                           interrupted=lambda: "interrupted (Ctrl-C); no file was left half-written; rerun merge")
    kept = {"checkpoint": ""}  # the checkpoint's path, known once the output is checked

    def interrupted():
        where = kept["checkpoint"] if os.path.isfile(kept["checkpoint"]) else None
        what = f"finished chunks are kept in {where}" if where else "no chunk had finished (nothing to keep)"
        return f"interrupted (Ctrl-C); {what}; rerun with --resume to continue"

    return run_command(lambda: _render(args, kept), interrupted=interrupted,
                       cancelled="cancelled; finished chunks are saved, rerun with --resume")


@dataclass
class _Merged:
    """What ``merge`` reports (:func:`.stderr_lines.run_command`)."""

    tiles: int
    path: str
    outputs: list
    refused: list

    def summary(self) -> str:
        return f"merged {self.tiles} tile(s) into {self.path}"


def _merge(args) -> _Merged:
    from .outputs import merge_exr

    done = {"written": [], "refused": []}
    path = merge_exr(args.tiles, args.output, overwrite=args.overwrite, preview=not args.no_preview, report=done)
    return _Merged(len(args.tiles), path, done["written"], done["refused"])


def _render(args, kept):
    """The ``render`` command's job: the local pass of the open file (:func:`.pipeline.run_local_pass`)."""
    import bpy

    from .blend_output import check_blend_output, save_blend
    from .output_paths import checkpoint_path, resolve
    from .pipeline import run_local_pass, scene_settings

    mode = args.mode
    settings = scene_settings(bpy.context.scene)
    if mode is None:
        mode = str(settings.mode).lower() if settings is not None else "pixels"
    if args.output is None:
        raise ValueError("render needs --output FILE.exr (pixels mode) or --output FILE.blend (vertices mode)")
    output = args.output
    if mode == "vertices":
        output = check_blend_output(output, args.overwrite)
    elif args.objects:
        raise ValueError("--objects applies to vertices mode only (--mode vertices)")
    kept["checkpoint"] = checkpoint_path(resolve(output))
    reporter = None if args.quiet else StderrProgress()
    report = run_local_pass(
        output=output, mode=mode, attribute=args.attribute, region=_region(args.region),
        tile=args.tile, resume=args.resume, samples=args.samples, missing=args.missing,
        progress=reporter, status=None if reporter is None else reporter.stage, preview=not args.no_preview,
        overwrite=args.overwrite, objects=args.objects, radiance_attribute=args.radiance_attribute,
        irradiance_attribute=args.irradiance_attribute, workers=args.workers,
        tolerance=args.tolerance,
    )
    if mode == "vertices":
        report.outputs.append(save_blend(output))
    return report
