"""Which processes of a launched graph have exited, and why: the exit status and the last error
line of each one's log (its ``[FATAL] ... cannot start: ...`` line, a traceback's last line).

Imports no rclpy: :func:`~nbv_prob_cnn.ros.graph.run_graph` and ``launch_scripts/robot.py``
watch their nodes with it, so that a launcher never waits on a graph whose node has died.
"""

from __future__ import annotations

import re
import signal
import subprocess
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from pathlib import Path

#: Lines that say what went wrong: rcutils' FATAL and ERROR lines, the last line of a Python
#: traceback (``ValueError: ...``), the interpreter's own fatal errors (a segmentation fault).
ERROR_LINE = re.compile(
    r"\[(FATAL|ERROR)\]|^Fatal Python error|^([A-Za-z_][\w.]*\.)?[A-Za-z_]\w*(Error|Exception|Interrupt)\b"
)
#: How much of the end of a log is searched for the last error line [bytes] (a node that ran for
#: hours writes a long log; what ended it is near its end).
LOG_TAIL_BYTES = 256 * 1024


def last_error_line(log: Path | None) -> str:
    """The last ``[FATAL]`` line of ``log`` (what ended one of our nodes, though an error of its
    shutdown may follow it), else the last line :data:`ERROR_LINE` matches, else its last
    non-empty line, else a note that there is none (no log, an empty log)."""
    if log is None:
        return "(no log: the graph was started without a log folder)"
    try:
        with open(log, "rb") as handle:
            handle.seek(0, 2)
            size = handle.tell()
            handle.seek(max(0, size - LOG_TAIL_BYTES))
            text = handle.read().decode("utf-8", errors="replace")
    except OSError as exc:
        return f"(its log cannot be read: {exc})"
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    fatal = [line for line in lines if "[FATAL]" in line]
    errors = fatal or [line for line in lines if ERROR_LINE.search(line)]
    if errors:
        return errors[-1]
    return lines[-1] if lines else "(its log is empty)"


@dataclass(frozen=True)
class NodeExit:
    """A process of the graph that has exited.

    Attributes:
        name: its name in the graph (its log is ``<name>.log``).
        status: its exit status (negative: the signal that ended it, as :class:`subprocess.Popen`).
        log: its log file (None: the graph keeps no logs).
        error_line: :func:`last_error_line` of that log.
    """

    name: str
    status: int
    log: Path | None
    error_line: str

    def how(self) -> str:
        """``status 1`` or ``killed by SIGSEGV``."""
        if self.status >= 0:
            return f"status {self.status}"
        try:
            return f"killed by {signal.Signals(-self.status).name}"
        except ValueError:
            return f"killed by signal {-self.status}"

    def describe(self) -> str:
        """Two lines for the user: which process ended how, its last error line and its log."""
        where = f"its log: {self.log}" if self.log is not None else "no log kept"
        return f"{self.name} exited ({self.how()}): {self.error_line}\n    {where}"


def exited_nodes(
    processes: Mapping[str, subprocess.Popen], log_dir: Path | None, may_exit: Collection[str] = ()
) -> list[NodeExit]:
    """The processes that have exited, in start order, but those of ``may_exit`` that ended with
    status 0 (a node that finishes its work, as ``bag_replay`` after the last message)."""
    found = []
    for name, proc in processes.items():
        status = proc.poll()
        if status is None or (status == 0 and name in may_exit):
            continue
        log = log_dir / f"{name}.log" if log_dir is not None else None
        found.append(NodeExit(name, status, log, last_error_line(log)))
    return found


__all__ = ["ERROR_LINE", "NodeExit", "exited_nodes", "last_error_line"]
