"""Batched forward kinematics and camera Jacobians of the joint chain that carries the camera.

Pinocchio evaluates one configuration per call; inverse kinematics with restarts and the
capability map need thousands at once, so the chain from the root to the camera is unrolled here
into numpy arrays (one fixed placement and one axis per joint) and evaluated for ``N``
configurations in one go. Tests compare it with pinocchio's forward kinematics.
"""

from __future__ import annotations

import numpy as np

from nbv_prob_cnn.arm.robot import RobotModel


class CameraChain:
    """The revolute/prismatic joints between the world and the camera, batched.

    Args:
        robot: the robot model (base pose and camera mount included).

    Attributes:
        n: number of chain joints (IK variables).
        lower, upper: their limits ``(n,)``.
        q_index: their indices into the full configuration vector.
    """

    def __init__(self, robot: RobotModel) -> None:
        model = robot.model
        joint = model.frames[robot.camera_frame].parentJoint
        joints = []
        while joint > 0:
            joints.append(joint)
            joint = model.parents[joint]
        joints.reverse()
        placements, axes, prismatic = [], [], []
        for index in joints:
            name = model.joints[index].shortname()
            placements.append(model.jointPlacements[index].homogeneous)
            prismatic.append("Prismatic" in name or name.startswith("JointModelP"))
            axes.append(_joint_axis(model.joints[index], name))
        self.placements = np.array(placements)  # (n, 4, 4): parent joint frame -> joint frame at q = 0
        self.axes = np.array(axes)  # (n, 3) in the joint frame
        self.prismatic = np.array(prismatic, dtype=bool)
        self.tip = model.frames[robot.camera_frame].placement.homogeneous  # last joint -> camera
        self.q_index = np.array([model.idx_qs[j] for j in joints], dtype=np.int64)
        self.n = len(joints)
        self.lower = robot.lower[self.q_index]
        self.upper = robot.upper[self.q_index]

    def camera_poses(self, q: np.ndarray, jacobian: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
        """World poses of the camera for chain configurations ``q (N, n)``.

        Returns:
            ``(poses (N, 4, 4), J (N, 6, n) or None)``; ``J`` maps joint velocities to the
            camera's linear velocity (rows 0-2) and angular velocity (rows 3-5), both in
            world axes.
        """
        q = np.atleast_2d(np.asarray(q, dtype=np.float64))
        count = q.shape[0]
        current = np.broadcast_to(np.eye(4), (count, 4, 4)).copy()
        origins = np.empty((count, self.n, 3))
        world_axes = np.empty((count, self.n, 3))
        for j in range(self.n):
            current = current @ self.placements[j]
            origins[:, j] = current[:, :3, 3]
            world_axes[:, j] = current[:, :3, :3] @ self.axes[j]
            current = current @ _joint_motion(self.axes[j], bool(self.prismatic[j]), q[:, j])
        poses = current @ self.tip
        if not jacobian:
            return poses, None
        jac = np.zeros((count, 6, self.n))
        tip = poses[:, :3, 3]
        for j in range(self.n):
            if self.prismatic[j]:
                jac[:, :3, j] = world_axes[:, j]
            else:
                jac[:, :3, j] = np.cross(world_axes[:, j], tip - origins[:, j])
                jac[:, 3:, j] = world_axes[:, j]
        return poses, jac

    def full_configuration(self, chain_q: np.ndarray, base_q: np.ndarray) -> np.ndarray:
        """Full configuration(s): ``base_q`` with the chain joints replaced by ``chain_q``."""
        chain_q = np.asarray(chain_q, dtype=np.float64)
        full = np.broadcast_to(np.asarray(base_q, dtype=np.float64), chain_q.shape[:-1] + base_q.shape[-1:]).copy()
        full[..., self.q_index] = chain_q
        return full


def _joint_axis(joint, name: str) -> np.ndarray:
    """Unit axis of a 1-DoF pinocchio joint, in its own frame."""
    for suffix, axis in (("X", (1.0, 0.0, 0.0)), ("Y", (0.0, 1.0, 0.0)), ("Z", (0.0, 0.0, 1.0))):
        if name in (f"JointModelR{suffix}", f"JointModelP{suffix}"):
            return np.array(axis)
    if "Unaligned" in name:
        unaligned = np.asarray(joint.extract().axis if hasattr(joint, "extract") else joint.axis, dtype=np.float64)
        return unaligned / np.linalg.norm(unaligned)
    raise ValueError(f"robot: joint type {name} is not supported on the camera chain (revolute/prismatic only)")


def _joint_motion(axis: np.ndarray, prismatic: bool, values: np.ndarray) -> np.ndarray:
    """``(N, 4, 4)`` transforms of a joint moved by ``values`` along/about ``axis``."""
    count = values.shape[0]
    motion = np.broadcast_to(np.eye(4), (count, 4, 4)).copy()
    if prismatic:
        motion[:, :3, 3] = values[:, None] * axis
        return motion
    skew = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    sin, cos = np.sin(values)[:, None, None], np.cos(values)[:, None, None]
    motion[:, :3, :3] = np.eye(3) + sin * skew + (1.0 - cos) * (skew @ skew)
    return motion
