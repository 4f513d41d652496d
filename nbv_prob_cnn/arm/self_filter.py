"""Self-filter: remove the depth pixels that see the robot itself.

The robot's bodies are placed by forward kinematics at the current joint state and ray cast from
the camera (:class:`~nbv_prob_cnn.arm.robot_scene.RobotScene`, rebuilt only when the joint state changes).
A measured pixel is the robot when the robot covers it and the measurement is not in front of the
robot by more than ``tolerance_m``; those pixels become 0 ("no return"), so they neither mark
occupied cells nor carve free space. Collision bodies are used by default: they mostly enclose
the visual meshes, so the filter errs towards removing a little more; ``bodies="both"`` (the
union with the visual meshes) also removes the few silhouette pixels where a visual mesh sticks
out of its collision body (what the ``integrator`` node uses against ``sim_camera render_arm``).
"""

from __future__ import annotations

import numpy as np

from nbv_prob_cnn.arm.robot import RobotModel
from nbv_prob_cnn.arm.robot_scene import RobotScene
from nbv_prob_cnn.perception.depth_camera import Intrinsics, check_pose


class RobotSelfFilter:
    """Renders the robot at a configuration and masks it out of depth images.

    Args:
        robot: robot model.
        bodies: ``"collision"``, ``"visual"`` or ``"both"`` geometries of the URDF.
        tolerance_m: measured depth this much in front of the rendered robot still counts as robot.
    """

    def __init__(self, robot: RobotModel, bodies: str = "collision", tolerance_m: float = 0.02) -> None:
        if not (np.isfinite(tolerance_m) and tolerance_m >= 0):
            raise ValueError(f"tolerance_m: expected a finite value >= 0, got {tolerance_m}")
        self.robot = robot
        self.tolerance_m = float(tolerance_m)
        self.scene = RobotScene(robot, bodies)

    def robot_meshes(self, q: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """``(vertices, faces)`` of every body in world coordinates at configuration ``q``."""
        return self.scene.robot_meshes(q)

    def robot_depth(self, q: np.ndarray, intrinsics: Intrinsics, pose_world_from_optical: np.ndarray) -> np.ndarray:
        """Depth image of the robot alone (0 where the robot is not seen)."""
        return self.scene.depth(q, intrinsics, pose_world_from_optical)

    def mask(self, depth_m: np.ndarray, q: np.ndarray, intrinsics: Intrinsics, pose: np.ndarray) -> np.ndarray:
        """``(H, W)`` bool: pixels of ``depth_m`` (float metres, 0 = no return) that see the robot.

        Raises:
            ValueError: image shape not matching the intrinsics, bad pose or configuration.
        """
        depth = np.asarray(depth_m, dtype=np.float32)
        if depth.shape != intrinsics.shape:
            raise ValueError(f"depth: shape {depth.shape} does not match the intrinsics {intrinsics.shape}")
        robot = self.robot_depth(q, intrinsics, check_pose(pose, "pose_world_from_optical"))
        return (robot > 0) & (depth > 0) & (depth >= robot - self.tolerance_m)

    def filter(self, depth_m: np.ndarray, q: np.ndarray, intrinsics: Intrinsics, pose: np.ndarray) -> np.ndarray:
        """A copy of ``depth_m`` with the robot's pixels set to 0 (no return)."""
        depth = np.array(depth_m, dtype=np.float32, copy=True)
        depth[self.mask(depth, q, intrinsics, pose)] = 0.0
        return depth
