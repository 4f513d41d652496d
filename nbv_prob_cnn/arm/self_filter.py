"""Self-filter: remove the depth pixels that see the robot itself.

The robot's bodies are placed by forward kinematics at the current joint state and ray cast from
the camera (the same open3d ``RaycastingScene`` as :class:`~nbv_prob_cnn.perception.depth_camera.DepthCamera`).
A measured pixel is the robot when the robot covers it and the measurement is not in front of the
robot by more than ``tolerance_m``; those pixels become 0 ("no return"), so they neither mark
occupied cells nor carve free space. Collision bodies are used by default: they enclose the
visual meshes, so the filter errs towards removing a little more.
"""

from __future__ import annotations

import numpy as np

from nbv_prob_cnn.arm.collision import body_mesh
from nbv_prob_cnn.arm.robot import RobotModel
from nbv_prob_cnn.perception.depth_camera import DepthCamera, Intrinsics, check_pose


class RobotSelfFilter:
    """Renders the robot at a configuration and masks it out of depth images.

    Args:
        robot: robot model.
        bodies: ``"collision"`` or ``"visual"`` geometry of the URDF.
        tolerance_m: measured depth this much in front of the rendered robot still counts as robot.
    """

    def __init__(self, robot: RobotModel, bodies: str = "collision", tolerance_m: float = 0.02) -> None:
        import pinocchio as pin

        if bodies not in ("collision", "visual"):
            raise ValueError(f"bodies: expected 'collision' or 'visual', got {bodies!r}")
        if not (np.isfinite(tolerance_m) and tolerance_m >= 0):
            raise ValueError(f"tolerance_m: expected a finite value >= 0, got {tolerance_m}")
        self.robot = robot
        self.tolerance_m = float(tolerance_m)
        self._pin = pin
        self.geometry_model = robot.collision_model if bodies == "collision" else robot.visual_model
        self.geometry_data = pin.GeometryData(self.geometry_model)
        self.data = robot.model.createData()
        self.meshes = [body_mesh(obj) for obj in self.geometry_model.geometryObjects]

    def robot_meshes(self, q: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """``(vertices, faces)`` of every body in world coordinates at configuration ``q``."""
        q = self.robot.check_q(q)
        self._pin.forwardKinematics(self.robot.model, self.data, q)
        self._pin.updateGeometryPlacements(self.robot.model, self.data, self.geometry_model, self.geometry_data)
        out = []
        for index, mesh in enumerate(self.meshes):
            pose = self.geometry_data.oMg[index].homogeneous
            out.append((np.asarray(mesh.vertices) @ pose[:3, :3].T + pose[:3, 3], np.asarray(mesh.faces)))
        return out

    def robot_depth(self, q: np.ndarray, intrinsics: Intrinsics, pose_world_from_optical: np.ndarray) -> np.ndarray:
        """Depth image of the robot alone (0 where the robot is not seen)."""
        return DepthCamera(self.robot_meshes(q), intrinsics).render(pose_world_from_optical)

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
