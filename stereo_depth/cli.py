"""The `stereo-depth` command: one subcommand per offline job.

Each subcommand lives in its own module under `stereo_depth.commands` with `add_parser(subparsers)`
and `run(args) -> int`. Errors of our own type end the command with one `ERROR:` line and exit 1.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

import stereo_depth.commands
from stereo_depth.errors import StereoDepthError


def _command_modules() -> list[str]:
    """Every module in stereo_depth.commands that defines add_parser is a subcommand."""
    names = [m.name for m in pkgutil.iter_modules(stereo_depth.commands.__path__) if not m.ispkg]
    return sorted(f"stereo_depth.commands.{n}" for n in names)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="stereo-depth", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in _command_modules():
        module = importlib.import_module(name)
        if hasattr(module, "add_parser"):
            module.add_parser(sub)
    return parser


def one_line(text: str) -> str:
    """A reason on one line: messages quoting a parser (YAML marks, numpy) may carry newlines."""
    return " ".join(text.split())


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.run(args))
    except StereoDepthError as exc:
        print(f"ERROR: {one_line(str(exc))}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("ERROR: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
