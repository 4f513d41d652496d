"""Topic, service and action names of the node suite, relative to the node's namespace.

Run with no namespace they resolve to the documented absolute names (``nbv/grid`` is
``/nbv/grid``); started with ``--ros-args -r __ns:=/robot1`` a whole graph moves to
``/robot1/nbv/grid`` and so on, so two graphs can run side by side in one domain. Bags keep the
absolute names of :mod:`nbv_prob_cnn.perception.bags`. Imports no rclpy.
"""

from __future__ import annotations

from nbv_prob_cnn.perception.bags import TOPIC_CAMERA_INFO, TOPIC_IMAGE, TOPIC_POSE


def relative(name: str) -> str:
    """``/camera/pose`` -> ``camera/pose``: the name resolved in the node's namespace."""
    return name.lstrip("/")


# topics
GRID = "nbv/grid"
GRID_COMPRESSED = GRID + "/compressed"  # the same grids as CompressedVoxelGrid (image_transport's naming)
NEXT_BEST_VIEW = "nbv/next_best_view"
MARKERS = "nbv/markers"
DEPTH_IMAGE = relative(TOPIC_IMAGE)
CAMERA_INFO = relative(TOPIC_CAMERA_INFO)
CAMERA_POSE = relative(TOPIC_POSE)
GOAL_POSE = "camera/goal_pose"
JOINT_STATES = "joint_states"
ARM_CAMERA_POSE = "arm/camera_pose"
ARM_TRAJECTORY = "arm/joint_trajectory"
# services
PLAN = "nbv/plan"
COMPLETE = "nbv/complete"
RANK_VIEWS = "nbv/rank_views"
EVALUATE_VIEWS = "nbv/evaluate_views"
MOVE_TO = "sim_camera/move_to"
MOVE_TO_JOINTS = "arm_sim/move_to_joints"
INTEGRATOR_RESET = "integrator/reset"
INTEGRATOR_SAVE = "integrator/save"
INTEGRATOR_SAVE_MESH = "integrator/save_mesh"
#: The occupied cells of the integrator's grid (PointCloud2, for RViz).
INTEGRATOR_OCCUPIED_CELLS = "integrator/occupied_cells"
INTEGRATOR_DIAGNOSTICS = "integrator/diagnostics"
#: The grid as an OctoMap (octomap_msgs/Octomap), the octomap_bridge's ``~/octomap``.
OCTOMAP_BRIDGE_OCTOMAP = "octomap_bridge/octomap"
#: MoveIt's planning scene diffs (move_group's planning scene monitor subscribes to it).
PLANNING_SCENE = "planning_scene"
#: octomap_server's binary map (the default of ``grid_source:=octomap``).
OCTOMAP_BINARY = "octomap_binary"
#: The robot-wide diagnostics topic (absolute: every node reports there).
DIAGNOSTICS = "/diagnostics"
# actions
EXPLORE = "nbv/explore"
