"""Results that are empty for a reason the user can fix, and the exit codes a script can rely on.

A command that ran on valid input and found nothing (a fusion with no return inside the box, a
plan on a grid without an empty cell to put a camera in) raises :class:`EmptyResultError` with one line
that says what and the likely fix; the ``nbv`` command line prints it and exits with
:data:`EXIT_EMPTY`. The codes (README, "Exit codes"):

* :data:`EXIT_OK` 0: done, with a result;
* :data:`EXIT_FAILED` 1: an unexpected failure (a traceback: please report it);
* :data:`EXIT_BAD_INPUT` 2: an argument or input file refused (the message names it), argparse's usage errors too;
* :data:`EXIT_EMPTY` 3: ran, but the result is empty (the message says why and what to try).
"""

from __future__ import annotations

import numpy as np

from nbv_prob_cnn.basics.grid import EMPTY, UNKNOWN

__all__ = ["EXIT_BAD_INPUT", "EXIT_EMPTY", "EXIT_FAILED", "EXIT_OK", "EmptyResultError", "no_view_reason"]

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_EMPTY = 3


class EmptyResultError(Exception):
    """Valid input, empty result; the message is one line: what is empty, why and the likely fix."""


def no_view_reason(state: np.ndarray) -> str:
    """Why no view of ``state`` has a positive gain, and what to try, in one line (no leading capital)."""
    state = np.asarray(state)
    if not np.any(state == EMPTY):
        seen = "nothing was seen" if np.all(state == UNKNOWN) else "only occupied cells were seen"
        return (
            f"the grid has no empty cell to put a camera in ({seen}): did the camera's returns fall inside the "
            "grid's box? Fuse with `nbv integrate --bounds auto`, or give --origin/--shape around the recording"
        )
    if not np.any(state == UNKNOWN):
        return "nothing is unknown: the grid is fully explored"
    return (
        "no candidate view sees an unknown cell: the unknown cells lie out of the sensor's range from every empty "
        "cell (or outside --workspace); widen the workspace or fuse more views"
    )
