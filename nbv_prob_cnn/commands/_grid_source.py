"""``--octomap`` beside ``--grid``: the arguments that read a grid from an OctoMap file, shared by
``nbv plan`` and ``nbv view``."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_octomap_arguments(parser: argparse.ArgumentParser, source) -> None:
    """``--octomap`` in the mutually exclusive group ``source`` (beside ``--grid``), ``--box`` and
    ``--occupancy-threshold``."""
    from nbv_prob_cnn.perception.octomap_codec import DEFAULT_OCCUPANCY_THRESHOLD

    source.add_argument(
        "--octomap", type=Path, help="OctoMap OcTree file (.bt, or .ot), e.g. from octomap_server's octomap_saver"
    )
    parser.add_argument(
        "--box",
        nargs=6,
        type=float,
        metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
        help="with --octomap: the grid's box in the tree's frame, metres, corners on the tree's lattice "
        "(default: the bounds of the tree's known leaves)",
    )
    parser.add_argument(
        "--occupancy-threshold",
        type=float,
        default=DEFAULT_OCCUPANCY_THRESHOLD,
        help="with --octomap: a leaf at or above this occupancy probability is occupied (default: %(default)s, "
        "OctoMap's)",
    )


def read_grid(args: argparse.Namespace):
    """The :class:`~nbv_prob_cnn.perception.saved_grid.SavedGrid` of ``--grid`` or ``--octomap``.

    Raises:
        ValueError: ``--box`` without ``--octomap``, and what the readers raise.
    """
    if args.octomap is None:
        from nbv_prob_cnn.perception.saved_grid import read_saved_grid

        if args.box is not None:
            raise ValueError("--box applies to --octomap only (a grid file has its own box)")
        return read_saved_grid(args.grid)
    from nbv_prob_cnn.perception.octomap_codec import read_octomap_grid

    box = None if args.box is None else (args.box[:3], args.box[3:])
    return read_octomap_grid(args.octomap, box, args.occupancy_threshold)


def source_text(args: argparse.Namespace) -> str:
    """``--grid PATH`` or ``--octomap PATH``, as the user gave it (for messages)."""
    return f"--octomap {args.octomap}" if args.octomap is not None else f"--grid {args.grid}"
