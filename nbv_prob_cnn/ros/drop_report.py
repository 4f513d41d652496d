"""The ``integrator``'s account of the depth frames it could not use: no frame is dropped silently.

Every frame that cannot be used is counted under its reason
(:class:`~nbv_prob_cnn.perception.messages.DropReason`: ``bad_message``, ``bad_encoding`` (not
REP-118), ``size_mismatch`` (image data vs. its sizes, or image vs. camera_info),
``non_finite_pose`` (NaN/inf or zero quaternion), ``pose_frame`` (pose not in ``fixed_frame``),
``no_pose`` / ``no_camera_info`` / ``no_joint_states`` (nothing within the tolerance before
``pose_timeout_s``), ``tf_unknown_frame`` / ``tf_not_connected`` / ``tf_extrapolation``
(``pose_source:=tf``), ``bad_joint_states``,
``too_many_pending``, ``behind``, ``reset``, ``integration_error``), logged (at most every 5 s
per reason) and reported on ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray`` every
``diagnostics_period_s``, status ``<node>: depth frames``: ERROR when frames were dropped in the
last period for bad input or a failure (the reasons logged as errors: ``bad_message``,
``bad_encoding``, ``size_mismatch``, ``non_finite_pose``, ``bad_joint_states``,
``integration_error``), WARN for the other reasons, OK otherwise; one key per reason)
and by ``/integrator/diagnostics`` (``std_srvs/Trigger``: ``success`` says that the call worked,
``message`` is a JSON object with the counts and the last drop's text per reason).
"""

from __future__ import annotations

import time
from typing import Any, Protocol

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from nbv_prob_cnn.perception.messages import DropCounts, DropReason

#: Each reason's drops are logged at most once in this period [s].
LOG_PERIOD_S = 5.0
#: Keys of the node's report that :meth:`DropReport.status` spreads into one key per entry (or leaves out).
_NESTED = ("dropped", "last_drop", "lost_in_transport", "inputs")


class Logger(Protocol):
    """What a drop is logged with (an rclpy node's logger)."""

    def error(self, message: str) -> Any: ...

    def warning(self, message: str) -> Any: ...


class DropReport:
    """The frames dropped per reason, the text of each reason's last drop, their log and their
    ``/diagnostics`` status (see the module)."""

    def __init__(self, logger: Logger) -> None:
        self.counts = DropCounts()  # every frame not integrated is counted here under its reason
        self._logger = logger
        self._last_text: dict[str, str] = {}  # reason -> why its last frame was dropped
        self._error_reasons: set[str] = set()  # reasons of drops that were errors (bad input, a failure)
        self._last_log: dict[DropReason, float] = {}  # reason -> when (time.monotonic) it was last logged
        self._reported: dict[str, int] = {}  # reason -> drops published on /diagnostics so far

    def drop(self, reason: DropReason, text: str, n: int = 1, error: bool = False) -> None:
        """Count ``n`` dropped frames under ``reason`` and log why (at most every
        :data:`LOG_PERIOD_S` per reason; as an error with ``error``: bad input or a failure)."""
        self.counts.add(reason, n)
        self._last_text[reason.value] = text
        if error:
            self._error_reasons.add(reason.value)
        now = time.monotonic()
        if now - self._last_log.get(reason, -float("inf")) < LOG_PERIOD_S:
            return
        self._last_log[reason] = now
        text = f"{text} ({self.counts.counts[reason.value]} dropped for {reason.value} so far)"
        if error:
            self._logger.error(text)
        else:
            self._logger.warning(text)

    def report(self) -> dict[str, Any]:
        """``dropped`` (per reason), ``dropped_total`` and ``last_drop`` (the last drop's text per reason)."""
        return {
            "dropped": self.counts.as_dict(),
            "dropped_total": self.counts.total(),
            "last_drop": dict(self._last_text),
        }

    def status(self, name: str, hardware_id: str, report: dict[str, Any]) -> DiagnosticStatus:
        """The status ``name`` of the node's ``report`` (its diagnostics, with :meth:`report`'s keys):
        the level and message by the drops since the last status, one key per value (``dropped``,
        ``last_drop`` and ``lost_in_transport`` one per entry; ``inputs`` left out)."""
        new = {k: n - self._reported.get(k, 0) for k, n in report["dropped"].items()}
        new = {k: n for k, n in new.items() if n}
        self._reported = dict(report["dropped"])
        level = DiagnosticStatus.OK
        if new:
            level = DiagnosticStatus.ERROR if self._error_reasons & set(new) else DiagnosticStatus.WARN
        reasons = ", ".join(f"{k} {n}" for k, n in new.items())
        status = DiagnosticStatus(
            level=level,
            name=name,
            message=f"{sum(new.values())} frame(s) dropped in the last period ({reasons})" if new else "integrating",
            hardware_id=hardware_id,
        )
        values = {k: v for k, v in report.items() if k not in _NESTED}
        values.update({f"lost_in_transport_{k}": v for k, v in report["lost_in_transport"].items()})
        values.update({f"dropped_{k}": v for k, v in report["dropped"].items()})
        values.update({f"last_drop_{k}": v for k, v in report["last_drop"].items()})
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        return status
