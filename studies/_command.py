"""The ``main`` of a study written as a command (``HELP``, ``add_arguments(parser)``, ``run(args)``,
as the product's ``nbv_prob_cnn/commands``): :func:`run_command`."""

from __future__ import annotations

import argparse
from collections.abc import Callable


def run_command(
    name: str,
    help_text: str,
    add_arguments: Callable[[argparse.ArgumentParser], None],
    run: Callable[[argparse.Namespace], int],
    argv: list[str] | None,
) -> int:
    """Parse ``argv`` with the options of study ``name`` (usage lines as ``nbv study NAME``) and run it."""
    parser = argparse.ArgumentParser(prog=f"nbv study {name}", description=help_text)
    add_arguments(parser)
    return run(parser.parse_args(argv))
