"""Collision checks of arm configurations: self-collision (coal meshes) and links against the grid.

Grid rule: a link collides when one of its sample points lies in a cell that is OCCUPIED or
UNKNOWN (unknown counts as an obstacle; optionally grown by ``margin_cells``; an optional
tabletop prior ``free_above_m`` lets unknown cells above a height pass). Sample points fill
each collision body's convex hull on a cubic lattice (``spacing``, default 0.75 cell) plus its
vertices, computed once per body in the body frame and moved by forward kinematics. Points
outside the grid are free (the grid bounds the mapped volume). Bodies fixed to the root (the
mount) are not checked against the grid.

Self-collision: every pair of collision bodies except those on the same or on adjacent joints,
and pairs already in contact at the robot's reference configuration (their meshes overlap at
rest), the usual "adjacent / always in contact" rule of arm set-ups.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy import ndimage

from nbv_prob_cnn.arm.robot import RobotModel
from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.basics.grid import EMPTY, OCCUPIED, check_state


def body_mesh(obj):
    """A ``trimesh.Trimesh`` of a pinocchio geometry object, in its own frame.

    Raises:
        ValueError: a shape other than mesh, box, sphere, cylinder or capsule.
    """
    import coal
    import trimesh

    shape = obj.geometry
    if isinstance(shape, coal.Box):
        return trimesh.creation.box(extents=2.0 * np.asarray(shape.halfSide))
    if isinstance(shape, coal.Sphere):
        return trimesh.creation.icosphere(subdivisions=2, radius=shape.radius)
    if isinstance(shape, coal.Cylinder):
        return trimesh.creation.cylinder(radius=shape.radius, height=2.0 * shape.halfLength)
    if isinstance(shape, coal.Capsule):
        return trimesh.creation.capsule(radius=shape.radius, height=2.0 * shape.halfLength)
    if obj.meshPath:
        mesh = trimesh.load(obj.meshPath, force="mesh", process=False)
        mesh.apply_scale(np.asarray(obj.meshScale, dtype=np.float64))
        return mesh
    raise ValueError(f"robot: collision body {obj.name!r} has an unsupported shape {type(shape).__name__}")


def hull_points(mesh, spacing: float) -> np.ndarray:
    """Points of a cubic lattice (``spacing``) inside the mesh's convex hull, plus the hull's vertices."""
    hull = mesh.convex_hull
    lo, hi = hull.bounds
    axes = [np.arange(a + spacing / 2.0, b, spacing) for a, b in zip(lo, hi, strict=True)]
    lattice = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    normals, offsets = hull.face_normals, np.einsum("ij,ij->i", hull.face_normals, hull.triangles[:, 0])
    inside = np.all(lattice @ normals.T <= offsets + 1e-9, axis=1)
    return np.vstack([lattice[inside], hull.vertices])


@dataclass
class GridObstacles:
    """Cells an arm link may not enter: occupied or unknown (grown by ``margin_cells``)."""

    blocked: np.ndarray
    geometry: GridGeometry

    @classmethod
    def from_state(
        cls, state: np.ndarray, geometry: GridGeometry, margin_cells: int = 0, free_above_m: float | None = None
    ) -> GridObstacles:
        """Obstacles of a ternary grid.

        ``free_above_m`` is an optional scene prior (a tabletop whose objects are all lower than
        that height): unknown cells whose centre lies at or above it do not block.

        Raises:
            ValueError: invalid grid, a grid whose shape differs from ``geometry``, or a negative margin.
        """
        state = check_state(state)
        if state.shape != tuple(geometry.shape) or state.ndim != 3:
            raise ValueError(f"state: expected a 3D grid of shape {tuple(geometry.shape)}, got {state.shape}")
        if margin_cells < 0:
            raise ValueError(f"margin_cells: expected >= 0, got {margin_cells}")
        blocked = state != EMPTY
        if free_above_m is not None:
            if not np.isfinite(free_above_m):
                raise ValueError(f"free_above_m: expected a finite height in metres, got {free_above_m}")
            z = geometry.origin[2] + (np.arange(state.shape[2]) + 0.5) * geometry.resolution
            blocked[:, :, z >= free_above_m] &= state[:, :, z >= free_above_m] == OCCUPIED
        if margin_cells:
            blocked = ndimage.binary_dilation(blocked, iterations=int(margin_cells))
        return cls(blocked, geometry)

    def cleared(self, points: np.ndarray) -> GridObstacles:
        """A copy with the cells holding ``points (N, 3)`` unblocked (the space the arm fills now
        is free of other obstacles, whatever the map says: unknown, or the arm seen as occupied)."""
        cell, inside = self.geometry.containing_cell(points)
        blocked = self.blocked.copy()
        c = cell[inside]
        blocked[c[:, 0], c[:, 1], c[:, 2]] = False
        return GridObstacles(blocked, self.geometry)

    @cached_property
    def _padded(self) -> np.ndarray:
        """``blocked`` with one free cell around it, flattened: a point outside the grid looks up
        the border (outside the grid nothing blocks) without an inside mask."""
        return np.pad(self.blocked, 1).ravel()

    def hits(self, points: np.ndarray) -> np.ndarray:
        """Which world points ``(N, 3)`` lie in a blocked cell (the cell of
        :meth:`~nbv_prob_cnn.basics.geometry.GridGeometry.containing_cell`; outside the grid: no)."""
        return self._look_up(np.floor(self.geometry.to_index(points) + 0.5))

    @cached_property
    def _box_counts(self) -> np.ndarray:
        """Summed-volume table of ``blocked``: entry ``[i, j, k]`` counts the blocked cells below
        ``(i, j, k)`` on every axis (one more entry per axis than cells)."""
        counts = np.zeros(tuple(n + 1 for n in self.blocked.shape), dtype=np.int32)
        counts[1:, 1:, 1:] = self.blocked.cumsum(0, dtype=np.int32).cumsum(1).cumsum(2)
        return counts

    def any_blocked_between(self, lo: np.ndarray, hi: np.ndarray) -> bool:
        """Whether a blocked cell lies in the box of cells ``lo .. hi`` (inclusive, clipped to the grid)."""
        shape = np.asarray(self.blocked.shape)
        a = np.clip(np.asarray(lo, dtype=np.int64), 0, shape)
        b = np.clip(np.asarray(hi, dtype=np.int64) + 1, 0, shape)
        if np.any(b <= a):
            return False
        c = self._box_counts
        total = (c[b[0], b[1], b[2]] - c[a[0], b[1], b[2]] - c[b[0], a[1], b[2]] - c[b[0], b[1], a[2]]
                 + c[a[0], a[1], b[2]] + c[a[0], b[1], a[2]] + c[b[0], a[1], a[2]] - c[a[0], a[1], a[2]])  # fmt: skip
        return bool(total > 0)

    def posed_hits(
        self, points: np.ndarray, pose: np.ndarray, bounds: tuple[np.ndarray, np.ndarray] | None = None
    ) -> bool:
        """Whether any of a body's points ``(N, 3)`` (its own frame) lies in a blocked cell when the
        body stands at ``pose`` (4×4, world): :meth:`hits` of the world points, with the pose and
        the cell scaling applied in one product. ``bounds``: the points' box in the body frame
        ``(lo, hi)``; when no blocked cell lies in the cells of its posed box (a conservative
        test), the points are not looked up."""
        g = self.geometry
        if bounds is not None:
            centre, half = (bounds[0] + bounds[1]) / 2.0, (bounds[1] - bounds[0]) / 2.0
            world_centre = pose[:3, :3] @ centre + pose[:3, 3]
            world_half = np.abs(pose[:3, :3]) @ half
            lo = np.floor(g.to_index(world_centre - world_half) + 0.5)
            hi = np.floor(g.to_index(world_centre + world_half) + 0.5)
            if not self.any_blocked_between(lo, hi):
                return False
        scale = pose[:3, :3].T / g.resolution
        offset = (pose[:3, 3] - np.asarray(g.origin)) / g.resolution
        return bool(self._look_up(np.floor(points @ scale + offset)).any())

    def _look_up(self, cell: np.ndarray) -> np.ndarray:
        shape = np.asarray(self.geometry.shape)
        c = (np.clip(cell, -1, shape) + 1).astype(np.intp)  # index into the padded grid
        flat = (c[:, 0] * (shape[1] + 2) + c[:, 1]) * (shape[2] + 2) + c[:, 2]
        return self._padded[flat]


class CollisionChecker:
    """Self- and grid collision of a robot's configurations.

    Args:
        robot: the robot model.
        spacing: lattice spacing (metres) of the grid-collision sample points.
    """

    def __init__(self, robot: RobotModel, spacing: float) -> None:
        import pinocchio as pin

        if not (np.isfinite(spacing) and spacing > 0):
            raise ValueError(f"spacing: expected a positive distance in metres, got {spacing}")
        self.robot = robot
        self.pin = pin
        model, geometry_model = robot.model, robot.collision_model
        self.geometry_model = geometry_model
        geometry_model.removeAllCollisionPairs()
        objects = geometry_model.geometryObjects
        for a in range(len(objects)):
            for b in range(a + 1, len(objects)):
                ja, jb = objects[a].parentJoint, objects[b].parentJoint
                if ja == jb or model.parents[ja] == jb or model.parents[jb] == ja:
                    continue
                geometry_model.addCollisionPair(pin.CollisionPair(a, b))
        self.geometry_data = pin.GeometryData(geometry_model)
        data = model.createData()
        pin.computeCollisions(model, data, geometry_model, self.geometry_data, robot.reference_q, False)
        in_contact = [
            pair
            for k, pair in enumerate(geometry_model.collisionPairs)
            if self.geometry_data.collisionResults[k].isCollision()
        ]
        for pair in in_contact:
            geometry_model.removeCollisionPair(pair)
        self.disabled_at_reference = [(objects[p.first].name, objects[p.second].name) for p in in_contact]
        self.geometry_data = pin.GeometryData(geometry_model)
        self.data = data
        self.moving = [i for i, obj in enumerate(objects) if obj.parentJoint > 0]
        self.points = {i: hull_points(body_mesh(objects[i]), spacing) for i in self.moving}
        #: Per moving body the box ``(lo, hi)`` of its sample points in its own frame.
        self.bounds = {i: (p.min(axis=0), p.max(axis=0)) for i, p in self.points.items()}
        camera_joint = model.frames[robot.camera_frame].parentJoint
        #: Bodies that move rigidly with the camera while only the chain joints move (the camera's
        #: own joint and the joints below it, e.g. the hand and the fingers).
        self.camera_rigid = [i for i in self.moving if camera_joint in list(model.supports[objects[i].parentJoint])]

    @property
    def n_pairs(self) -> int:
        return len(self.geometry_model.collisionPairs)

    def self_collision(self, q: np.ndarray) -> bool:
        """True when two non-adjacent bodies intersect at ``q``."""
        q = self.robot.check_q(q)
        return bool(
            self.pin.computeCollisions(self.robot.model, self.data, self.geometry_model, self.geometry_data, q, True)
        )

    def body_poses(self, q: np.ndarray) -> dict[int, np.ndarray]:
        """World poses of the moving collision bodies at ``q``."""
        q = self.robot.check_q(q)
        self.pin.forwardKinematics(self.robot.model, self.data, q)
        self.pin.updateGeometryPlacements(self.robot.model, self.data, self.geometry_model, self.geometry_data)
        return {i: self.geometry_data.oMg[i].homogeneous for i in self.moving}

    def body_points(self, q: np.ndarray) -> np.ndarray:
        """World positions ``(N, 3)`` of every moving body's sample points at ``q``."""
        poses = self.body_poses(q)
        return np.vstack([self.points[i] @ pose[:3, :3].T + pose[:3, 3] for i, pose in poses.items()])

    def camera_rigid_points(self, q: np.ndarray) -> np.ndarray:
        """Sample points ``(M, 3)`` of the camera-rigid bodies (:attr:`camera_rigid`) in the
        optical frame at ``q``; they stay there for any move of the chain joints alone, so a
        camera pose ``T`` puts them at ``points @ T[:3, :3].T + T[:3, 3]`` without IK."""
        poses = self.body_poses(q)
        camera_from_world = np.linalg.inv(self.robot.camera_pose(q))
        local = []
        for i in self.camera_rigid:
            camera_from_body = camera_from_world @ poses[i]
            local.append(self.points[i] @ camera_from_body[:3, :3].T + camera_from_body[:3, 3])
        return np.vstack(local) if local else np.zeros((0, 3))

    def grid_collisions(self, q: np.ndarray, obstacles: GridObstacles) -> list[str]:
        """Names of the bodies that enter a blocked cell at ``q`` (empty list: free)."""
        names = []
        for i, pose in self.body_poses(q).items():
            points = self.points[i] @ pose[:3, :3].T + pose[:3, 3]
            if np.any(obstacles.hits(points)):
                names.append(self.geometry_model.geometryObjects[i].name)
        return names

    def grid_collision(self, q: np.ndarray, obstacles: GridObstacles) -> bool:
        """True when any moving body enters a blocked cell at ``q`` (stops at the first that does)."""
        return any(obstacles.posed_hits(self.points[i], pose, self.bounds[i]) for i, pose in self.body_poses(q).items())

    def is_free(self, q: np.ndarray, obstacles: GridObstacles) -> bool:
        """Neither self-collision nor grid collision at ``q``."""
        return not self.self_collision(q) and not self.grid_collision(q, obstacles)

    def path_is_free(self, q_start: np.ndarray, q_goal: np.ndarray, obstacles: GridObstacles, step: float) -> bool:
        """Straight joint-space segment checked at samples at most ``step`` rad apart (both ends included)."""
        q_start, q_goal = self.robot.check_q(q_start, "q_start"), self.robot.check_q(q_goal, "q_goal")
        count = max(1, int(np.ceil(np.abs(q_goal - q_start).max() / step)))
        for t in np.linspace(0.0, 1.0, count + 1)[::-1]:  # goal first: most likely to fail
            if not self.is_free(q_start + t * (q_goal - q_start), obstacles):
                return False
        return True
