"""``octomap_msgs/Octomap`` and MoveIt's ``PlanningScene`` diff to and from our grids: the messages
around :mod:`nbv_prob_cnn.perception.octomap_codec`.

A grid whose corner is not on its own cells' lattice (a whole number of cells from the frame's
origin) cannot be an OcTree in its frame as it is: :func:`grid_to_octomap_msg` then moves the
cells to the nearest lattice point (by less than half a cell; the shift is returned so that the
caller can say so), while :func:`planning_scene_diff` stays exact, since its ``OctomapWithPose``
carries the corner as its ``origin``."""

from __future__ import annotations

import array

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Pose
from nbv_prob_cnn_msgs.msg import VoxelGrid
from octomap_msgs.msg import Octomap, OctomapWithPose
from std_msgs.msg import Header

from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.perception.octomap_codec import (
    DEFAULT_OCCUPANCY_THRESHOLD,
    OctreeStream,
    decode,
    encode_binary,
    leaves_to_grid,
)
from nbv_prob_cnn.ros.conversions import grid_to_msg

__all__ = ["grid_to_octomap_msg", "octomap_stream", "octomap_to_grid_msg", "planning_scene_diff"]


def _lattice_geometry(geometry: GridGeometry) -> tuple[GridGeometry, np.ndarray]:
    """``geometry`` with its corner moved to the nearest point of its cells' lattice, and that shift [m]."""
    origin = np.asarray(geometry.origin, dtype=np.float64)
    snapped = np.round(origin / geometry.resolution) * geometry.resolution
    corner = (float(snapped[0]), float(snapped[1]), float(snapped[2]))
    return GridGeometry(corner, geometry.resolution, geometry.shape), snapped - origin


def _octomap(stream: OctreeStream, frame_id: str, stamp: Time | None) -> Octomap:
    msg = Octomap(header=Header(stamp=stamp or Time(), frame_id=frame_id), binary=True, id=stream.tree_id)
    msg.resolution = float(stream.resolution)
    msg.data = array.array("b", stream.data)
    return msg


def grid_to_octomap_msg(
    state: np.ndarray, geometry: GridGeometry, frame_id: str, stamp: Time | None = None,
    unknown_as_occupied: bool = True,
) -> tuple[Octomap, np.ndarray]:  # fmt: skip
    """The grid as a binary ``OcTree`` message in ``frame_id``, and the shift [m] of its cells onto
    the OcTree's lattice (zeros when the grid's corner is on it).

    Raises:
        OctomapError: not a 3D grid, or beyond the tree's key range.
    """
    lattice, shift = _lattice_geometry(geometry)
    return _octomap(encode_binary(state, lattice, unknown_as_occupied), frame_id, stamp), shift


def planning_scene_diff(
    state: np.ndarray, geometry: GridGeometry, frame_id: str, stamp: Time | None = None,
    unknown_as_occupied: bool = True, octomap: Octomap | None = None,
):  # fmt: skip
    """A ``moveit_msgs/PlanningScene`` diff (``is_diff``) whose ``world.octomap`` is the grid: the
    tree with the grid's corner at its own origin, placed by ``origin`` at the corner in
    ``frame_id`` (exact for any corner). ``octomap``: the grid's message from
    :func:`grid_to_octomap_msg`, reused (with the identity origin) when its shift was zero."""
    from moveit_msgs.msg import PlanningScene

    scene = PlanningScene(is_diff=True)
    header = Header(stamp=stamp or Time(), frame_id=frame_id)
    if octomap is not None:
        placed = OctomapWithPose(header=header, origin=Pose(), octomap=octomap)
    else:
        at_zero = GridGeometry((0.0, 0.0, 0.0), geometry.resolution, geometry.shape)
        origin = Pose()
        origin.position.x, origin.position.y, origin.position.z = (float(v) for v in geometry.origin)
        tree = _octomap(encode_binary(state, at_zero, unknown_as_occupied), frame_id, stamp)
        placed = OctomapWithPose(header=header, origin=origin, octomap=tree)
    scene.world.octomap = placed
    return scene


def octomap_stream(msg: Octomap) -> OctreeStream:
    """The tree an ``Octomap`` message carries (its ``data`` as bytes)."""
    data = msg.data
    raw = data.tobytes() if isinstance(data, array.array) else np.asarray(data, dtype=np.int8).tobytes()
    return OctreeStream(msg.id, float(msg.resolution), bool(msg.binary), raw)


def octomap_to_grid_msg(
    msg: Octomap, box_min, box_max, occupancy_threshold: float = DEFAULT_OCCUPANCY_THRESHOLD
) -> VoxelGrid:
    """The ``VoxelGrid`` of the message's tree inside ``[box_min, box_max]`` (metres, the message's
    frame; corners on the tree's lattice), in the message's frame and with its stamp.

    Raises:
        OctomapError: another tree id, a truncated or corrupt stream, a box the tree's resolution cannot take.
    """
    state, geometry = leaves_to_grid(decode(octomap_stream(msg), occupancy_threshold), box_min, box_max)
    return grid_to_msg(state, geometry, msg.header.frame_id, msg.header.stamp)
