"""``blender -b [scene.blend] -c hemisphere_local_pass render|merge|solve ...``: the command-line entry point.

Registered with ``bpy.utils.register_cli_command`` (Blender 4.2+) by ``registration.register()``.
The handler is an argparse program that makes no UI calls and returns the process exit code; the
sub-commands (``render``, ``merge``) and their options belong to ``job.cli_main``. Under Blender 3.4,
which has no ``--command``, the same program runs as ``blender -b scene.blend --python-exit-code 1
--python-expr "...; from hemisphere_local_pass.blender import job; sys.exit(job.cli_main([...]))"``
(both parts are needed for a non-zero exit on errors; docs/blender.md).
"""

import argparse
import sys

COMMAND = "hemisphere_local_pass"
SUBCOMMANDS = ("render", "merge", "solve")
PROG = f"blender --command {COMMAND}"

__all__ = ["COMMAND", "PROG", "handler"]


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
        from . import job
    except ImportError as ex:  # a broken installation: one line, non-zero
        print(f"{PROG}: error: cannot load the job module: {ex}", file=sys.stderr)
        return 1
    try:
        return int(job.cli_main(argv) or 0)
    except SystemExit as ex:  # argparse inside the job (--help, bad options) exits; Blender must not
        code = ex.code
        return code if isinstance(code, int) else (0 if code is None else 1)
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
