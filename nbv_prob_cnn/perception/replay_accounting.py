"""What a bag replay delivered: the integrator's frame counts since the replay started.

``bag_replay`` reads the integrator's diagnostics (the JSON of ``/integrator/diagnostics``) before
its first frame and after each one; :func:`replay_delta` turns two such reports into the counts
of this replay and :func:`replay_line` into the closing log line
``sent N, integrated M, dropped K by reason (...)``. Imports no rclpy.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass
class ReplayDelta:
    """The integrator's counts accrued between two diagnostics reports."""

    received: int  # depth images the integrator received
    integrated: int
    pending: int  # received, neither integrated nor dropped yet (at the later report)
    dropped: dict[str, int] = field(default_factory=dict)  # reason -> frames (only reasons that grew)
    lost_in_transport: dict[str, int] = field(default_factory=dict)  # topic -> messages DDS reported lost
    skipped_still: int = 0  # frames of a still camera the integrator did not fuse (still_frames_fused)

    @property
    def dropped_total(self) -> int:
        return sum(self.dropped.values())


def replay_delta(before: dict[str, Any], after: dict[str, Any]) -> ReplayDelta:
    """Counts of ``after`` minus those of ``before`` (two integrator diagnostics reports).

    Raises:
        ValueError: a report without the integrator's counts, or counts that went down (another
            integrator answered, or it restarted in between).
    """
    for name, report in (("before", before), ("after", after)):
        missing = [key for key in ("images", "integrated", "dropped") if key not in report]
        if missing:
            raise ValueError(f"{name}: not an integrator diagnostics report (no {', '.join(missing)})")

    def grew(key: str, old: int, new: int) -> int:
        if new < old:
            raise ValueError(f"{key} went down from {old} to {new}: the integrator restarted during the replay")
        return int(new) - int(old)

    dropped = {
        reason: grew(f"dropped {reason}", before["dropped"].get(reason, 0), count)
        for reason, count in after["dropped"].items()
    }
    lost_before = before.get("lost_in_transport", {})
    lost = {
        topic: grew(f"lost {topic}", lost_before.get(topic, 0), count)
        for topic, count in after.get("lost_in_transport", {}).items()
    }
    return ReplayDelta(
        received=grew("images", before["images"], after["images"]),
        integrated=grew("integrated", before["integrated"], after["integrated"]),
        pending=int(after.get("pending", 0)),
        dropped={reason: n for reason, n in dropped.items() if n},
        lost_in_transport={topic: n for topic, n in lost.items() if n},
        skipped_still=grew("skipped_still", before.get("skipped_still", 0), after.get("skipped_still", 0)),
    )


def replay_line(sent: int, delta: ReplayDelta | None) -> str:
    """``sent N, integrated M, dropped K by reason (...)``; without integrator diagnostics
    (``delta`` None) only what was sent, and that nothing is known of the rest."""
    if delta is None:
        return f"sent {sent} frame(s); integrated and dropped unknown (no integrator diagnostics answered)"
    reasons = ", ".join(f"{reason} {n}" for reason, n in sorted(delta.dropped.items())) or "none"
    line = (
        f"sent {sent}, integrated {delta.integrated}, dropped {delta.dropped_total} by reason ({reasons}); "
        f"received {delta.received}"
    )
    if delta.skipped_still:
        line += f", {delta.skipped_still} skipped from a still camera (still_frames_fused)"
    if delta.pending:
        line += f", {delta.pending} still pending"
    unseen = sent - delta.received
    if unseen > 0:
        lost = ", ".join(f"{t} {n}" for t, n in sorted(delta.lost_in_transport.items())) or "none reported by DDS"
        line += f"; {unseen} sent but never received (lost in transport: {lost})"
    return line


__all__ = ["ReplayDelta", "replay_delta", "replay_line"]
