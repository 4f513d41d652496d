"""The log line of one exploration step: where its time went (no ROS here; the times are those of
a ``PlanNextBestView`` response, or of anything with the same fields)."""

from __future__ import annotations

from typing import Protocol


class PlanTimes(Protocol):
    """A plan's times (s) and exact-check count, as ``PlanNextBestView.Response`` has them (a
    near-camera fallback: both passes, its two rankings and two arm checks, summed)."""

    time_total_s: float
    time_cnn_s: float
    time_raycast_s: float
    time_views_s: float
    time_rank_s: float
    time_capability_s: float
    time_ik_collision_s: float
    arm_checked: int


def fallback_note(fallback: bool, found: str) -> str:
    """The view line's note on a near-camera fallback: ``" (fallback after 300 checked: 300 in
    collision)"`` with ``found`` what the first pass found (the plan response's ``message``,
    :meth:`~nbv_prob_cnn.arm.feasibility.FeasibilityReport.fallback_text`); ``""`` without one."""
    if not fallback:
        return ""
    return f" ({found or 'fallback: no ranked view was feasible'})"


def stage_times(planned: PlanTimes, move_s: float, grid_wait_s: float) -> str:
    """Where one exploration step's time went, for the log: planning (its CNN, ray casting and
    view search; with the ranking's and the arm's times in the response also the rest of the
    ranking (transport, reply), the capability map and the IK/collision checks; the rest being
    message conversion), the move, and the wait for a grid that includes a frame from the new pose."""
    parts = (planned.time_cnn_s, planned.time_raycast_s, planned.time_views_s)
    arm = planned.time_capability_s + planned.time_ik_collision_s
    ranking = ""
    if planned.time_rank_s or arm:
        reply = max(0.0, planned.time_rank_s - parts[1] - parts[2])
        ranking = (
            f", rank reply {reply:.2f}, capability {planned.time_capability_s:.2f}, IK+collision "
            f"{planned.time_ik_collision_s:.2f} ({planned.arm_checked} checked)"
        )
        rest = max(0.0, planned.time_total_s - parts[0] - max(planned.time_rank_s, parts[1] + parts[2]) - arm)
    else:
        rest = max(0.0, planned.time_total_s - sum(parts))
    return (
        f"plan {planned.time_total_s:.2f} s (CNN {parts[0]:.2f}, ray casting {parts[1]:.2f}, views {parts[2]:.2f}"
        f"{ranking}, other {rest:.2f}), move {move_s:.2f} s, grid wait {grid_wait_s:.2f} s"
    )


def server_stage_times(times: dict[str, float]) -> str:
    """The servers' own times on the last plan's requests (``time_total_s`` of /nbv/complete and
    /nbv/rank_views, the completion's inference time), for the log: set beside the planner's
    round trips they show what the transport costs; empty when the plan made no such request."""
    parts = []
    if "cnn_server" in times:
        parts.append(f"completion server {times['cnn_server']:.2f} (inference {times['cnn_inference']:.2f})")
    if "rank_server" in times:
        parts.append(f"ranking server {times['rank_server']:.2f}")
    return f"; servers: {', '.join(parts)}" if parts else ""
