"""RViz markers of planning results: candidate views coloured by gain, the chosen frustum."""

from __future__ import annotations

import math

import numpy as np
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from nbv_prob_cnn.basics.camera import matrix_from_quaternion


def _gain_colour(value: float) -> ColorRGBA:
    """Blue (low) to red (high) for ``value`` in [0, 1]."""
    v = float(np.clip(value, 0.0, 1.0))
    return ColorRGBA(r=v, g=0.2, b=1.0 - v, a=0.9)


def frustum_corners(position: np.ndarray, quat: np.ndarray, hfov_deg: float, vfov_deg: float, depth: float):
    """The apex and four far corners of a camera frustum (REP-103 optical frame)."""
    rot = matrix_from_quaternion(quat)
    tx, ty = math.tan(math.radians(hfov_deg) / 2), math.tan(math.radians(vfov_deg) / 2)
    corners = [
        rot @ np.array([sx * tx, sy * ty, 1.0]) * depth + position for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))
    ]
    return position, corners


def planning_markers(
    frame_id: str,
    stamp,
    views: list[tuple[np.ndarray, np.ndarray, float]],
    hfov_deg: float,
    vfov_deg: float,
    frustum_depth_m: float,
    arrow_length_m: float,
) -> MarkerArray:
    """Markers for ranked views ``(position, quaternion, gain)``, best first: one arrow per
    candidate along its optical axis, coloured by gain relative to the best, and the best
    view's frustum as lines."""
    array = MarkerArray()
    clear = Marker(action=Marker.DELETEALL)
    clear.header.frame_id = frame_id
    array.markers.append(clear)
    if not views:
        return array
    best_gain = max(g for _, _, g in views) or 1.0
    for index, (position, quat, gain) in enumerate(views):
        arrow = Marker(type=Marker.ARROW, action=Marker.ADD, ns="nbv_candidates", id=index)
        arrow.header.frame_id, arrow.header.stamp = frame_id, stamp
        tip = position + matrix_from_quaternion(quat)[:, 2] * arrow_length_m
        arrow.points = [Point(x=float(a), y=float(b), z=float(c)) for a, b, c in (position, tip)]
        arrow.scale.x, arrow.scale.y, arrow.scale.z = arrow_length_m * 0.08, arrow_length_m * 0.16, 0.0
        arrow.color = _gain_colour(gain / best_gain)
        array.markers.append(arrow)
    position, quat, _ = views[0]
    apex, corners = frustum_corners(position, quat, hfov_deg, vfov_deg or hfov_deg, frustum_depth_m)
    lines = Marker(type=Marker.LINE_LIST, action=Marker.ADD, ns="nbv_frustum", id=0)
    lines.header.frame_id, lines.header.stamp = frame_id, stamp
    lines.scale.x = frustum_depth_m * 0.01
    lines.color = ColorRGBA(r=1.0, g=0.85, b=0.0, a=1.0)
    segments = [(apex, c) for c in corners] + [(corners[i], corners[(i + 1) % 4]) for i in range(4)]
    lines.points = [Point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for seg in segments for p in seg]
    array.markers.append(lines)
    return array
