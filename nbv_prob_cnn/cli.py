"""The ``nbv`` command line. Each sub-command lives in its own module under
:mod:`nbv_prob_cnn.commands` and exposes ``NAME``, ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``."""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from nbv_prob_cnn import commands


def _command_modules():
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if not info.name.startswith("_"):
            yield importlib.import_module(f"{commands.__name__}.{info.name}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="nbv", description="Next best view planning for depth cameras.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in _command_modules():
        cmd = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(cmd)
        cmd.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one command; the exit codes: :mod:`nbv_prob_cnn.basics.results` (README, "Exit codes")."""
    from nbv_prob_cnn.basics.results import EXIT_BAD_INPUT, EXIT_EMPTY, EXIT_OK, EmptyResultError

    args = build_parser().parse_args(argv)  # usage errors exit with 2 (EXIT_BAD_INPUT)
    try:
        return int(args._run(args) or EXIT_OK)
    except EmptyResultError as exc:
        print(f"nbv {args.command}: nothing found: {exc}", file=sys.stderr)
        return EXIT_EMPTY
    except (ValueError, FileNotFoundError) as exc:
        print(f"nbv {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
