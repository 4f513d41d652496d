"""The arm's side of a planning request, as the ROS nodes need it (no ROS here): one
:class:`ArmFeasibility` per grid geometry (collision sample spacing and capability map depend on
the grid), and the reachability of arbitrary camera poses (``EvaluateViews``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nbv_prob_cnn.arm.capability import load_or_build_capability_map
from nbv_prob_cnn.arm.collision import CollisionChecker, GridObstacles
from nbv_prob_cnn.arm.feasibility import ArmFeasibility
from nbv_prob_cnn.arm.ik import solve_camera_poses
from nbv_prob_cnn.arm.path_planning import JointPathPlanner, PathPlannerSettings
from nbv_prob_cnn.arm.robot import RobotConfig, RobotModel
from nbv_prob_cnn.basics.camera import matrix_from_quaternion
from nbv_prob_cnn.basics.geometry import GridGeometry

#: Grid-collision sample spacing, in cells (as ``nbv study arm_compare``).
SAMPLE_SPACING_CELLS = 0.75


@dataclass
class ArmPlanningSetup:
    """How a node checks views with the arm.

    Args:
        config: the robot description.
        motion_weight: ``λ`` of the utility ``gain − λ·joint path length``.
        free_above_m: tabletop prior of :meth:`GridObstacles.from_state` (None: every unknown cell blocks).
        max_checks: exact checks per plan at most (0: no limit).
        capability_stride: lattice stride (cells) of the capability map (0: no map).
        seed: IK restarts' random seed.
        ik_alternatives: other IK solutions of a view tried when the first collides (:class:`ArmFeasibility`).
        strict_capability: the capability lookup ANDs the lattice nodes around a cell (:class:`ArmFeasibility`).
        path_planning: where the straight joint path to a view collides, plan one with these
            settings (:class:`JointPathPlanner`); None: straight paths only.
        roll_symmetric: a view turned 180° about its optical axis counts as the view (:class:`ArmFeasibility`).
    """

    config: RobotConfig
    motion_weight: float = 0.0
    free_above_m: float | None = None
    max_checks: int = 0
    capability_stride: int = 8
    seed: int = 0
    ik_alternatives: int = 0
    strict_capability: bool = False
    path_planning: PathPlannerSettings | None = None
    roll_symmetric: bool = False
    robot: RobotModel = field(init=False)
    _cache: dict = field(init=False, default_factory=dict)

    def __post_init__(self) -> None:
        self.robot = RobotModel(self.config)

    def feasibility(self, geometry: GridGeometry) -> ArmFeasibility:
        """The :class:`ArmFeasibility` of grids with this geometry (built, and its capability map
        loaded or built, on first use)."""
        key = (tuple(geometry.origin), float(geometry.resolution), tuple(geometry.shape))
        if key not in self._cache:
            if geometry.dims != 3:
                raise ValueError(f"the arm needs a 3D grid, got {geometry.dims}D")
            checker = CollisionChecker(self.robot, spacing=SAMPLE_SPACING_CELLS * geometry.resolution)
            capability = (
                load_or_build_capability_map(self.robot, geometry, self.capability_stride, progress=False)
                if self.capability_stride
                else None
            )
            self._cache[key] = ArmFeasibility(
                self.robot, checker, capability, motion_weight=self.motion_weight, free_above_m=self.free_above_m,
                max_checks=self.max_checks, rng=np.random.default_rng(self.seed),
                ik_alternatives=self.ik_alternatives, strict_capability=self.strict_capability,
                path_planner=None if self.path_planning is None else JointPathPlanner(checker, self.path_planning),
                roll_symmetric=self.roll_symmetric,
            )  # fmt: skip
        return self._cache[key]


def reachable_poses(
    arm: ArmFeasibility,
    positions: np.ndarray,
    quaternions: np.ndarray,
    state: np.ndarray,
    geometry: GridGeometry,
    current_q: np.ndarray,
) -> list[np.ndarray | None]:
    """Per camera pose (``positions (N, 3)`` m, optical-frame ``quaternions (N, 4)`` xyzw) an IK
    solution from ``current_q`` that is free of self-collision and of the grid's occupied/unknown
    cells (the cells the arm fills at ``current_q`` count as free), or None.

    No path check: the caller may not move from ``current_q``. Poses with NaN components or a
    zero quaternion are unreachable.

    Raises:
        ValueError: bad configuration, grid, or array shapes.
    """
    positions = np.asarray(positions, dtype=np.float64)
    quaternions = np.asarray(quaternions, dtype=np.float64)
    if positions.ndim != 2 or positions.shape[1] != 3 or quaternions.shape != (positions.shape[0], 4):
        raise ValueError(f"positions (N, 3) and quaternions (N, 4): got {positions.shape} and {quaternions.shape}")
    current_q = arm.robot.check_q(current_q, "current_q")
    obstacles = GridObstacles.from_state(state, geometry, arm.margin_cells, arm.free_above_m)
    obstacles = obstacles.cleared(arm.checker.body_points(current_q))
    valid = np.all(np.isfinite(positions), axis=1) & np.all(np.isfinite(quaternions), axis=1)
    valid &= np.any(quaternions != 0, axis=1)
    targets = np.broadcast_to(np.eye(4), (int(valid.sum()), 4, 4)).copy()
    targets[:, :3, :3] = [matrix_from_quaternion(q) for q in quaternions[valid]]
    targets[:, :3, 3] = positions[valid]
    solved = iter(solve_camera_poses(arm.chain, targets, current_q, arm.rng, arm.ik_settings))  # one batch
    solutions: list[np.ndarray | None] = []
    for ok in valid:
        q = next(solved).q if ok else None
        solutions.append(q if q is not None and arm.checker.is_free(q, obstacles) else None)
    return solutions


def arm_polyline(robot: RobotModel, q: np.ndarray) -> np.ndarray:
    """World positions ``(n, 3)`` of the root link, the origin of every joint between it and the
    camera, and the camera: the arm drawn as segments in pictures.

    Raises:
        ValueError: a configuration of the wrong length or with non-finite values.
    """
    import pinocchio as pin

    q = robot.check_q(q)
    model = robot.model
    joints, joint = [], model.frames[robot.camera_frame].parentJoint
    while joint > 0:
        joints.append(joint)
        joint = model.parents[joint]
    pin.forwardKinematics(model, robot.data, q)
    points = [robot.config.world_from_base[:3, 3]]
    points += [np.asarray(robot.data.oMi[j].translation, dtype=np.float64) for j in reversed(joints)]
    points.append(robot.camera_pose(q)[:3, 3])
    return np.array(points)
