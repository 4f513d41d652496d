"""The pure parts of ``nbv study soak`` (issue 18): the random mix of requests, process sampling from
/proc, and the report (markdown, CSV, PNG). Imports no rclpy: the ROS clients
(:mod:`studies.soak_explorer`, :mod:`studies.soak_requester`) write JSON-lines
event logs that :func:`build_report` reads.

A request is described by a :class:`RequestSpec` (service kind, valid or not, and the fields that
make it so); the requester turns it into the message. Valid requests should be answered with
success (they may still fail for a reason of the moment, e.g. a view in an occupied cell:
counted, not an error of the soak); invalid ones must be answered with ``success: false`` (a
rejected goal for the action). A request without an answer in time is a ``timeout``.
"""

from __future__ import annotations

import csv
import json
import math
import os
import random
import time
from collections import Counter, defaultdict
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

#: Service kinds of the simulated free-flying graph, with the service (action) each one calls.
KINDS: dict[str, str] = {
    "plan": "nbv/plan",
    "complete": "nbv/complete",
    "rank_views": "nbv/rank_views",
    "evaluate_views": "nbv/evaluate_views",
    "move_to": "sim_camera/move_to",
    "integrator_reset": "integrator/reset",
    "integrator_save": "integrator/save",
    "integrator_diagnostics": "integrator/diagnostics",
    "explore_goal": "nbv/explore",
}
#: Kinds whose requests cannot be invalid (``std_srvs/Trigger`` has no fields).
ALWAYS_VALID = frozenset({"integrator_reset", "integrator_diagnostics"})
#: Kinds sent only invalid: a second valid Explore goal would disturb the soak's explorations.
ALWAYS_INVALID = frozenset({"explore_goal"})
#: Relative weights of the kinds in the mix (the expensive ones, CNN and ray casting, rarer).
WEIGHTS: dict[str, float] = {
    "plan": 1.0,
    "complete": 1.0,
    "rank_views": 1.0,
    "evaluate_views": 2.0,
    "move_to": 1.0,
    "integrator_reset": 0.3,
    "integrator_save": 1.0,
    "integrator_diagnostics": 2.0,
    "explore_goal": 1.0,
}


@dataclass
class RequestSpec:
    """One request of the mix: what to call and what makes it valid or invalid."""

    kind: str
    valid: bool
    variant: str  # a short name of what the fields do ("unknown method", "empty path", ...)
    fields: dict[str, Any] = field(default_factory=dict)


def _variants(kind: str, valid: bool, grid_centre: tuple[float, float, float], save_dir: str) -> list[RequestSpec]:
    cx, cy, cz = grid_centre
    above = [cx, cy, cz + 0.45]  # a camera position above the scene, looking down
    if kind == "plan":
        if valid:
            return [RequestSpec(kind, True, "default method, 200 origins", {"max_origins": 200, "top_k": 1})]
        return [RequestSpec(kind, False, "unknown method", {"method": "no_such_method"})]
    if kind == "complete":
        if valid:
            return [RequestSpec(kind, True, "latest grid, dataset by shape", {"grid": "latest", "dataset": ""})]
        return [
            RequestSpec(kind, False, "empty grid", {"grid": "empty"}),
            RequestSpec(kind, False, "data shorter than its sizes", {"grid": "truncated"}),
            RequestSpec(kind, False, "unknown dataset", {"grid": "latest", "dataset": "no_such_dataset"}),
        ]
    if kind == "rank_views":
        if valid:
            return [
                RequestSpec(
                    kind,
                    True,
                    "prob_ig, 200 origins",
                    {"grid": "latest", "method": "prob_ig", "top_k": 3, "max_origins": 200},
                )
            ]
        # (an empty grid means the latest one and top_k 0 means 1: both valid by the .srv)
        return [
            RequestSpec(kind, False, "unknown method", {"grid": "latest", "method": "no_such_method", "top_k": 1}),
            RequestSpec(kind, False, "data shorter than its sizes", {"grid": "truncated", "method": "prob_ig",
                                                                     "top_k": 1}),
            RequestSpec(kind, False, "method prob without a probability grid", {"grid": "latest", "method": "prob",
                                                                                "top_k": 1}),
        ]  # fmt: skip
    if kind == "evaluate_views":  # poses as for move_to
        if valid:
            poses = [
                [*above, 1.0, 0.0, 0.0, 0.0],
                [cx - 0.3, cy, cz + 0.3, 1.0, 0.0, 0.0, 0.0],
                [float("nan"), 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            ]
            return [RequestSpec(kind, True, "3 poses (one NaN: that pose INVALID_POSE)", {"poses": poses})]
        return [
            RequestSpec(kind, False, "no poses", {"poses": []}),
            RequestSpec(kind, False, "unknown method", {"poses": [[*above, 1.0, 0.0, 0.0, 0.0]], "method": "nope"}),
        ]
    if kind == "move_to":  # poses [x, y, z, qx, qy, qz, qw]; (1, 0, 0, 0): the optical axis points down
        if valid:
            return [RequestSpec(kind, True, "above the scene, looking down", {"pose": [*above, 1.0, 0.0, 0.0, 0.0]})]
        return [
            RequestSpec(kind, False, "NaN position", {"pose": [float("nan"), cy, cz, 1.0, 0.0, 0.0, 0.0]}),
            RequestSpec(kind, False, "zero quaternion", {"pose": [*above, 0.0, 0.0, 0.0, 0.0]}),
        ]
    if kind == "integrator_save":
        if valid:
            return [RequestSpec(kind, True, "a file in the soak directory", {"path": f"{save_dir}/soak_grid.npz"})]
        return [
            RequestSpec(kind, False, "empty path", {"path": ""}),
            RequestSpec(kind, False, "missing directory", {"path": "/nonexistent_dir_of_the_soak/grid.npz"}),
        ]
    if kind in ALWAYS_VALID:
        return [RequestSpec(kind, True, "trigger")]
    if kind == "explore_goal":
        return [
            RequestSpec(kind, False, "max_views 0", {"max_views": 0}),
            RequestSpec(kind, False, "NaN stop_unknown_fraction", {"max_views": 3, "stop_unknown_fraction": math.nan}),
        ]
    raise ValueError(f"unknown request kind {kind!r}; expected one of {sorted(KINDS)}")


class RequestMix:
    """Random requests: a kind by :data:`WEIGHTS`, valid or invalid half the time (where both
    exist), then one of that kind's variants; seeded, so a soak can be repeated."""

    def __init__(self, seed: int, grid_centre: tuple[float, float, float], save_dir: str) -> None:
        self.rng = random.Random(seed)
        self.grid_centre = grid_centre
        self.save_dir = save_dir
        self.kinds = sorted(KINDS)

    def first_round(self) -> list[RequestSpec]:
        """Every kind once valid (where it can be) and once invalid (where it can be), so that even
        a short soak covers them all."""
        specs = []
        for kind in self.kinds:
            for valid in (True, False):
                if (valid and kind in ALWAYS_INVALID) or (not valid and kind in ALWAYS_VALID):
                    continue
                specs.append(_variants(kind, valid, self.grid_centre, self.save_dir)[0])
        return specs

    def next(self) -> RequestSpec:
        kind = self.rng.choices(self.kinds, weights=[WEIGHTS[k] for k in self.kinds])[0]
        valid = kind in ALWAYS_VALID or (kind not in ALWAYS_INVALID and self.rng.random() < 0.5)
        return self.rng.choice(_variants(kind, valid, self.grid_centre, self.save_dir))


# ----------------------------------------------------------------------- processes
@dataclass
class ProcessSample:
    """Resident memory and open file descriptors of one process at one time."""

    time_s: float  # seconds since the soak started
    node: str
    pid: int
    rss_kib: int
    fds: int


def sample_process(pid: int, proc: str = "/proc") -> tuple[int, int]:
    """``(VmRSS in KiB, open file descriptors)`` of process ``pid``.

    Raises:
        ProcessLookupError: no such process (it exited).
    """
    try:
        with open(f"{proc}/{pid}/status") as status:
            rss = next((int(line.split()[1]) for line in status if line.startswith("VmRSS:")), 0)
        fds = len(os.listdir(f"{proc}/{pid}/fd"))
    except FileNotFoundError as exc:
        raise ProcessLookupError(f"process {pid} is gone") from exc
    return rss, fds


class EventLog:
    """The writing side of :func:`read_events`: one JSON line per event, with its wall time
    (``time.time()``) under ``wall``, flushed at once so that a killed writer loses at most the
    line it was writing."""

    def __init__(self, path: Path) -> None:
        self._file = open(path, "a")  # noqa: SIM115 - closed by close()

    def write(self, **event: Any) -> None:
        self._file.write(json.dumps({"wall": time.time(), **event}) + "\n")
        self._file.flush()

    def close(self) -> None:
        self._file.close()


def read_events(path: Path) -> list[dict[str, Any]]:
    """The JSON lines of an event log (a torn last line, of a killed writer, is left out)."""
    if not path.exists():
        return []
    events = []
    for line in path.read_text().splitlines():
        try:
            events.append(json.loads(line))
        except ValueError:
            continue
    return events


# ----------------------------------------------------------------------- report
@dataclass
class RequestTally:
    """Outcomes of one kind of request, valid or invalid."""

    sent: int = 0
    success: int = 0  # answered success (goal accepted, for the action)
    error: int = 0  # answered success false (goal rejected)
    timeout: int = 0  # no answer in time
    unavailable: int = 0  # the service was not there (not called)


def tally_requests(events: list[dict[str, Any]]) -> dict[tuple[str, bool], RequestTally]:
    """Request outcomes by ``(kind, valid)`` from the requester's ``request`` events."""
    tallies: dict[tuple[str, bool], RequestTally] = defaultdict(RequestTally)
    for event in events:
        if event.get("event") != "request":
            continue
        tally = tallies[(event["kind"], bool(event["valid"]))]
        tally.sent += 1
        outcome = event["outcome"]
        if outcome not in ("success", "error", "timeout", "unavailable"):
            raise ValueError(f"request outcome {outcome!r}: expected success, error, timeout or unavailable")
        setattr(tally, outcome, getattr(tally, outcome) + 1)
    return dict(tallies)


def growth(samples: list[ProcessSample], node: str, t_from: float, key: str) -> tuple[int, int, float] | None:
    """``(value at the first sample at or after t_from, value at the last sample, growth)`` of a
    node's ``rss_kib`` or ``fds``; None without samples."""
    rows = sorted((s for s in samples if s.node == node), key=lambda s: s.time_s)
    after = [s for s in rows if s.time_s >= t_from]
    if not after:
        return None
    first, last = getattr(after[0], key), getattr(rows[-1], key)
    return first, last, (last - first) / first if first else 0.0


@dataclass
class SoakReport:
    """What ``nbv study soak`` reports (see :func:`build_report`)."""

    minutes: float
    requests: dict[tuple[str, bool], RequestTally]
    explorations: list[dict[str, Any]]
    crashes: list[str]  # "<node>: <why>"
    exit_codes: dict[str, int | None]
    dropped: dict[str, int]  # the integrator's drops per reason (its last diagnostics answer)
    images: int  # and its counts of images received / integrated
    integrated: int
    samples: list[ProcessSample]
    first_exploration_end_s: float | None
    ready_s: float  # when the explorer found the graph ready (the "start" of the memory table)
    shm_files: list[str]  # Fast DDS files the nodes mapped that were still in /dev/shm after the stop
    shm_leaked: list[str]  # of them, the ones no live process held (removed)
    notes: list[str] = field(default_factory=list)
    max_growth: float = 0.10  # largest allowed growth of RSS and fds after the first exploration

    def nodes(self) -> list[str]:
        return sorted({s.node for s in self.samples})

    def violations(self) -> list[str]:
        """The soak's invariants that failed: no crash; every kind sent and answered; every
        invalid request answered with an error; RSS and fds grew at most ``max_growth`` after
        the first exploration."""
        max_growth = self.max_growth
        out = [f"crash: {c}" for c in self.crashes]
        for kind in KINDS:
            sent = sum(t.sent for (k, _), t in self.requests.items() if k == kind)
            answered = sum(t.success + t.error for (k, _), t in self.requests.items() if k == kind)
            if sent == 0:
                out.append(f"{kind}: no request sent")
            elif answered == 0:
                out.append(f"{kind}: no request answered")
        for (kind, valid), tally in sorted(self.requests.items()):
            if not valid and tally.success:
                out.append(f"{kind}: {tally.success} invalid request(s) answered with success")
            if tally.timeout or tally.unavailable:
                out.append(
                    f"{kind} ({'valid' if valid else 'invalid'}): {tally.timeout} without an answer in time, "
                    f"{tally.unavailable} with the service unavailable"
                )
        if self.first_exploration_end_s is None:
            out.append("no exploration finished with a view")
        else:
            for node in self.nodes():
                for key in ("rss_kib", "fds"):
                    g = growth(self.samples, node, self.first_exploration_end_s, key)
                    if g is not None and g[2] > max_growth:
                        out.append(
                            f"{node}: {key} grew {100 * g[2]:.1f} % after the first exploration ({g[0]} -> {g[1]})"
                        )
        return out


def build_report(
    minutes: float,
    request_events: list[dict[str, Any]],
    explorer_events: list[dict[str, Any]],
    samples: list[ProcessSample],
    t0_wall: float,
    crashes: list[str],
    exit_codes: dict[str, int | None],
    shm_files: list[str],
    shm_leaked: list[str],
) -> SoakReport:
    """Gather the events of both clients and the process samples into a :class:`SoakReport`
    (``t0_wall``: the soak's start, ``time.time()``, for the events' wall times)."""
    explorations = [e for e in explorer_events if e.get("event") == "exploration"]
    ends = [e["end_wall"] - t0_wall for e in explorations if e.get("status") == "succeeded" and e.get("views")]
    diagnostics = [e for e in request_events if e.get("event") == "request" and e.get("report")]
    last = diagnostics[-1]["report"] if diagnostics else {}
    for e in explorer_events:  # the explorer's closing diagnostics are the latest
        if e.get("event") == "diagnostics":
            last = e["report"]
    dropped = {k: int(v) for k, v in last.get("dropped", {}).items() if v}
    return SoakReport(
        minutes=minutes,
        requests=tally_requests(request_events),
        explorations=explorations,
        crashes=list(crashes),
        exit_codes=dict(exit_codes),
        dropped=dropped,
        images=int(last.get("images", 0)),
        integrated=int(last.get("integrated", 0)),
        samples=list(samples),
        first_exploration_end_s=min(ends) if ends else None,
        ready_s=next((e["wall"] - t0_wall for e in explorer_events if e.get("event") == "ready"), 0.0),
        shm_files=sorted(shm_files),
        shm_leaked=sorted(shm_leaked),
    )


def _at(samples: list[ProcessSample], node: str, t: float | None, last: bool = False) -> ProcessSample | None:
    rows = sorted((s for s in samples if s.node == node), key=lambda s: s.time_s)
    if not rows:
        return None
    if last:
        return rows[-1]
    if t is None:
        return rows[0]
    return next((s for s in rows if s.time_s >= t), None)


def write_report(report: SoakReport, out_dir: Path, title: str, context: list[str]) -> list[Path]:
    """``soak.md`` (tables), ``requests.csv``, ``processes.csv`` (every sample) and
    ``processes.png`` (RSS in MiB and fds over time, one line per node). Returns the paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    requests_csv = out_dir / "requests.csv"
    with open(requests_csv, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["kind", "valid", "sent", "success", "error", "timeout", "unavailable"])
        for (kind, valid), t in sorted(report.requests.items()):
            writer.writerow([kind, valid, t.sent, t.success, t.error, t.timeout, t.unavailable])
    processes_csv = out_dir / "processes.csv"
    with open(processes_csv, "w", newline="") as handle:
        rows = csv.DictWriter(handle, fieldnames=["time_s", "node", "pid", "rss_kib", "fds"])
        rows.writeheader()
        for s in report.samples:
            rows.writerow(asdict(s))
    png = out_dir / "processes.png"
    _plot(report, png, title)

    lines = [f"# {title}", "", *context, ""]
    violations = report.violations()
    lines += ["## Verdict", "", "All invariants hold." if not violations else "Violations:", ""]
    lines += [f"- {v}" for v in violations] + ([""] if violations else [])
    lines += [
        "## Requests (second client, random mix)",
        "",
        "| kind | valid | sent | success | error answered | no answer in time | service unavailable |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for (kind, valid), t in sorted(report.requests.items()):
        lines.append(
            f"| {kind} | {'valid' if valid else 'invalid'} | {t.sent} | {t.success} | {t.error} | {t.timeout} "
            f"| {t.unavailable} |"
        )
    total = sum(t.sent for t in report.requests.values())
    errors = sum(t.error for t in report.requests.values())
    lines += [
        "",
        (
            f"{total} requests, {errors} answered with an error. A valid request may be answered with an error for "
            "a reason of the moment (e.g. a plan while the grid was just reset); `integrator_diagnostics` answers "
            "`success: true` whenever the call worked (the integrator's drops are in the frames section below); "
            "`explore_goal` errors are rejected goals."
        ),
        "",
    ]
    statuses = Counter(e.get("status", "?") for e in report.explorations)
    views = [int(e.get("views", 0)) for e in report.explorations]
    lines += [
        "## Explorations (first client; integrator reset before each)",
        "",
        f"{len(report.explorations)} explorations: "
        + ", ".join(f"{n} {s}" for s, n in sorted(statuses.items()))
        + (f"; {sum(views)} views in all ({min(views)}-{max(views)} each)" if views else ""),
        "",
    ]
    reasons = Counter(str(e.get("reason", "")) for e in report.explorations if e.get("status") != "succeeded")
    if reasons:
        lines += [f"- not succeeded: {r!r} x {n}" for r, n in reasons.most_common()] + [""]
    viewless = Counter(
        str(e.get("reason", "")) for e in report.explorations if e.get("status") == "succeeded" and not e.get("views")
    )
    if viewless:
        lines += [f"- succeeded without a view: {r!r} x {n}" for r, n in viewless.most_common()] + [""]
    lines += [
        "## Crashes",
        "",
        f"{len(report.crashes)} crash(es)." + "".join(f"\n- {c}" for c in report.crashes),
        "",
        "Exit codes at the stop (SIGINT): " + ", ".join(f"{n} {c}" for n, c in sorted(report.exit_codes.items())),
        "",
    ]
    lines += [
        "## Frames (integrator diagnostics at the end)",
        "",
        f"images received {report.images}, integrated {report.integrated}; dropped by reason: "
        + (", ".join(f"{r} {n}" for r, n in sorted(report.dropped.items())) or "none"),
        "",
    ]
    first_end = report.first_exploration_end_s
    lines += [
        "## Memory and file descriptors",
        "",
        (
            f"Start = first sample after the graph was ready ({report.ready_s:.0f} s); after the first exploration = "
            f"first sample after its end ({first_end or 0:.0f} s); "
            "growth = end against after the first exploration."
        ),
        "",
        "| node | RSS start [MiB] | after 1st [MiB] | end [MiB] | growth | fds start | after 1st | end | growth |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for node in report.nodes():
        start, mid, end = (
            _at(report.samples, node, report.ready_s),
            _at(report.samples, node, first_end),
            _at(report.samples, node, None, last=True),
        )
        if start is None or end is None:
            continue
        mid = mid or end

        def pct(a: int, b: int) -> str:
            return f"{100 * (b - a) / a:+.1f} %" if a else "n/a"

        lines.append(
            f"| {node} | {start.rss_kib / 1024:.1f} | {mid.rss_kib / 1024:.1f} | {end.rss_kib / 1024:.1f} | "
            f"{pct(mid.rss_kib, end.rss_kib)} | {start.fds} | {mid.fds} | {end.fds} | {pct(mid.fds, end.fds)} |"
        )
    lines += ["", f"![RSS and file descriptors over time]({png.name})", ""]
    lines += [
        "## /dev/shm at the end",
        "",
        f"{len(report.shm_files)} Fast DDS file(s) that the nodes mapped were still there after the graph stopped"
        + (": " + ", ".join(f"`{n}`" for n in report.shm_files) if report.shm_files else "")
        + "; "
        + f"{len(report.shm_leaked)} held by no process (removed by the soak, as the launch scripts do; "
        + "see docs/ros.md, 'Shared memory')"
        + (": " + ", ".join(f"`{n}`" for n in report.shm_leaked) if report.shm_leaked else "")
        + ".",
        "",
    ]
    lines += [f"- {n}" for n in report.notes]
    lines += [
        "",
        ("Files: [requests.csv](requests.csv), [processes.csv](processes.csv), [processes.png](processes.png)."),
    ]
    md = out_dir / "soak.md"
    md.write_text("\n".join(lines).rstrip() + "\n")
    return [md, requests_csv, processes_csv, png]


def _plot(report: SoakReport, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_rss, ax_fds) = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    for node in report.nodes():
        rows = sorted((s for s in report.samples if s.node == node), key=lambda s: s.time_s)
        t = [s.time_s / 60 for s in rows]
        ax_rss.plot(t, [s.rss_kib / 1024 for s in rows], label=node)
        ax_fds.plot(t, [s.fds for s in rows], label=node)
    if report.first_exploration_end_s is not None:
        for ax in (ax_rss, ax_fds):
            ax.axvline(
                report.first_exploration_end_s / 60, color="grey", ls="--", lw=0.8, label="end of the first exploration"
            )
    ax_rss.set_ylabel("resident memory (RSS) [MiB]")
    ax_fds.set_ylabel("open file descriptors")
    ax_fds.set_xlabel("time since the soak started [min]")
    ax_rss.set_title(title)
    ax_rss.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    ax_fds.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    for ax in (ax_rss, ax_fds):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


#: Lines of a crashed node's log shown in the report (a node killed at the stop has its thread stacks there).
LOG_TAIL_LINES = 60


def log_tail(path: Path, lines: int = LOG_TAIL_LINES) -> str:
    """The last ``lines`` lines of a node's log as a fenced block after a crash line ('' without a log)."""
    try:
        tail = path.read_text(errors="replace").splitlines()[-lines:]
    except OSError:
        return ""
    return f"; the end of its log ({path.name}):\n\n```\n" + "\n".join(tail) + "\n```\n"


__all__ = [
    "KINDS",
    "ProcessSample",
    "RequestMix",
    "RequestSpec",
    "RequestTally",
    "SoakReport",
    "build_report",
    "growth",
    "log_tail",
    "read_events",
    "sample_process",
    "tally_requests",
    "write_report",
]
