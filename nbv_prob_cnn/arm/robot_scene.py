"""The robot's own bodies as a ray-casting scene at a joint state.

Used twice: the simulated camera renders the arm into its depth images (``sim_camera
render_arm``, visual meshes) and the self-filter renders it to find the pixels that see it
(``integrator self_filter``, collision bodies). The bodies are loaded once; the scene is placed
by forward kinematics and rebuilt only when the joint state changes (a resting arm costs one
extra ray cast per frame).
"""

from __future__ import annotations

import numpy as np

from nbv_prob_cnn.arm.collision import body_mesh
from nbv_prob_cnn.arm.robot import RobotModel
from nbv_prob_cnn.perception.depth_camera import DepthCamera, Intrinsics, MeshScene

#: The URDF geometry a scene is made of; ``both`` is the union of the two (the pybullet Panda's
#: collision meshes do not enclose its visual meshes everywhere: a few silhouette pixels of the
#: visual meshes lie outside them).
BODIES = ("collision", "visual", "both")


class RobotScene:
    """The robot's bodies placed at a configuration, for ray casting.

    Args:
        robot: robot model.
        bodies: ``"collision"``, ``"visual"`` or ``"both"`` geometries of the URDF.
    """

    def __init__(self, robot: RobotModel, bodies: str = "collision") -> None:
        import pinocchio as pin

        if bodies not in BODIES:
            raise ValueError(f"bodies: expected one of {list(BODIES)}, got {bodies!r}")
        self.robot = robot
        self.bodies = bodies
        self._pin = pin
        self.geometry_models = [
            model
            for name, model in (("collision", robot.collision_model), ("visual", robot.visual_model))
            if bodies in (name, "both")
        ]
        self.geometry_data = [pin.GeometryData(model) for model in self.geometry_models]
        self.data = robot.model.createData()
        self.meshes = [body_mesh(obj) for model in self.geometry_models for obj in model.geometryObjects]
        self._scene_q: bytes | None = None
        self._scene: MeshScene | None = None
        self._cameras: dict[Intrinsics, DepthCamera] = {}
        self.rebuilds = 0

    def robot_meshes(self, q: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """``(vertices, faces)`` of every body in world coordinates at configuration ``q``."""
        q = self.robot.check_q(q)
        self._pin.forwardKinematics(self.robot.model, self.data, q)
        placements: list[np.ndarray] = []
        for model, data in zip(self.geometry_models, self.geometry_data, strict=True):
            self._pin.updateGeometryPlacements(self.robot.model, self.data, model, data)
            placements.extend(placement.homogeneous for placement in data.oMg)
        return [
            (np.asarray(mesh.vertices) @ pose[:3, :3].T + pose[:3, 3], np.asarray(mesh.faces))
            for mesh, pose in zip(self.meshes, placements, strict=True)
        ]

    def scene(self, q: np.ndarray) -> MeshScene:
        """The bodies at ``q`` as a :class:`~nbv_prob_cnn.perception.depth_camera.MeshScene`
        (the last one is kept and returned again while ``q`` stays the same).

        Raises:
            ValueError: wrong length or non-finite configuration.
        """
        q = self.robot.check_q(q)
        key = q.tobytes()
        if self._scene is None or key != self._scene_q:
            self._scene = MeshScene(self.robot_meshes(q))
            self._scene_q = key
            self.rebuilds += 1
        return self._scene

    def depth(self, q: np.ndarray, intrinsics: Intrinsics, pose_world_from_optical: np.ndarray) -> np.ndarray:
        """Depth image of the robot alone (0 where the robot is not seen)."""
        camera = self._cameras.get(intrinsics)
        if camera is None:
            if len(self._cameras) >= 4:  # a camera per image size seen; a changing size should not grow this
                self._cameras.clear()
            camera = self._cameras[intrinsics] = DepthCamera([], intrinsics)
        return camera.render(pose_world_from_optical, occluders=[self.scene(q)])
