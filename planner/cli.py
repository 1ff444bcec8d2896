"""Command line: `regrasp` and `python -m planner`.

A `PlannerError` becomes one line on stderr and exit code 2 (bad input) or the
command's own failure code; any other exception is a bug and shows its traceback.
"""

from __future__ import annotations

import argparse
import sys

from planner.errors import PlannerError


def _cmd_demo(args: argparse.Namespace) -> int:
    print("regrasp demo: the planner is not yet available")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="regrasp", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="plan (and replay) the bundled box example")
    demo.set_defaults(func=_cmd_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except PlannerError as err:
        print(f"regrasp {args.command}: error: {err}", file=sys.stderr)
        return getattr(args, "error_exit_code", 2)
