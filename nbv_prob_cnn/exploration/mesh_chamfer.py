"""The Chamfer distance of a simulated run's TSDF mesh against the world's ground-truth meshes.

The simulated explore loop labels cells by voxel ray casting (:func:`~nbv_prob_cnn.sensing.observe.observe`);
it keeps no TSDF. :class:`MeshReconstruction` adds one beside it: for each view taken it renders a
depth image of the world's triangle meshes (:meth:`~nbv_prob_cnn.worlds.world.World.triangle_meshes`)
through the voxel sensor's own rays (:func:`sensor_intrinsics`: the same fields of view and pixel
pitch as :func:`~nbv_prob_cnn.sensing.observe.camera_rays`, returns up to ``R_max`` along the ray)
and fuses it into a sparse :class:`~nbv_prob_cnn.perception.tsdf.TsdfIntegrator` over the world's grid. At
the end of a run :meth:`MeshReconstruction.chamfer` extracts the TSDF's marching-cubes mesh and
measures it against the ground truth, as
:func:`~nbv_prob_cnn.exploration.surface_metrics.chamfer_distance` does two point sets but with the
nearest point taken on the other mesh itself (open3d's exact point-to-triangle distance), so that
the spacing of the points adds nothing (among points drawn at 2 per cell face it would add about
0.35 cells to each term):

* **accuracy**: the mean distance from points spread uniformly over the TSDF mesh to the true meshes;
* **completeness**: the mean distance from points spread uniformly over the visible true surface
  to the TSDF mesh;
* **Chamfer distance**: their mean, ``(accuracy + completeness) / 2``.

Points: :data:`POINTS_PER_CELL_FACE` per ``resolution²`` of area
(:func:`~nbv_prob_cnn.exploration.surface_metrics.sample_surface`, seeded). The **visible** true
surface, as the surface of the coverage
(:meth:`~nbv_prob_cnn.exploration.surface_metrics.SurfaceCoverage.seen_from`), is what faces the
free space of the first view: a point whose cell half, one or one and a half cells away along its
triangle's normal, either way, is in that free space (:func:`~nbv_prob_cnn.exploration.surface_metrics.free_space_of`);
so not the parts of the table's slab no camera above it can see (its underside, facing the closed
gap below the table, and its sides on the box's faces), nor the faces of objects resting on it.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np

from nbv_prob_cnn.basics.camera import matrix_from_quaternion
from nbv_prob_cnn.basics.sensor import Sensor
from nbv_prob_cnn.exploration.surface_metrics import free_space_of, sample_surface, triangle_areas
from nbv_prob_cnn.sensing.observe import RAY_SPACING_CELLS
from nbv_prob_cnn.sensing.sensor_noise import SensorNoise
from nbv_prob_cnn.worlds.world import World

if TYPE_CHECKING:
    from nbv_prob_cnn.perception.depth_camera import Intrinsics

#: Points drawn per ``resolution²`` of mesh area, on the ground truth and on the reconstruction.
POINTS_PER_CELL_FACE = 4.0
#: At most this many points per mesh (a bound on the distance queries).
MAX_POINTS = 400_000
#: Seed of the point draws (the same world gives the same ground-truth points in every run).
POINT_SEED = 0
#: Key of a run's ``.json`` that holds its :meth:`ChamferResult.as_dict`.
CHAMFER_KEY = "chamfer"


@dataclass(frozen=True)
class ChamferResult:
    """The Chamfer distance of a TSDF mesh to the ground truth, in metres.

    Attributes:
        distance_m: ``(accuracy_m + completeness_m) / 2``; NaN when the TSDF has no surface yet.
        accuracy_m: mean distance from the reconstruction's points to the true surface.
        completeness_m: mean distance from the true surface's points to the reconstruction.
        mesh_vertices: vertices of the TSDF's mesh.
        views: depth images fused.
        seconds: time spent on rendering, fusion, meshing and the distances.
    """

    distance_m: float
    accuracy_m: float
    completeness_m: float
    mesh_vertices: int
    views: int
    seconds: float

    def as_dict(self) -> dict:
        """The fields, for a run's ``.json``."""
        return asdict(self)

    def describe(self) -> str:
        """``Chamfer 4.21 mm (accuracy 1.10 mm, completeness 7.32 mm; TSDF mesh of 5120 vertices from 20 views)``."""
        if self.mesh_vertices == 0:
            return f"Chamfer n/a (the TSDF of {self.views} views has no surface)"
        if not math.isfinite(self.distance_m):
            return "Chamfer n/a (no true surface faces the first view's free space)"
        return (
            f"Chamfer {1000 * self.distance_m:.2f} mm (accuracy {1000 * self.accuracy_m:.2f} mm, completeness "
            f"{1000 * self.completeness_m:.2f} mm; TSDF mesh of {self.mesh_vertices} vertices from {self.views} views)"
        )


def sensor_intrinsics(sensor: Sensor) -> Intrinsics:
    """The pinhole :class:`~nbv_prob_cnn.perception.depth_camera.Intrinsics` whose pixel rays are the
    3D voxel sensor's rays (:func:`~nbv_prob_cnn.sensing.observe.camera_rays`): ``nx × ny``
    pixels spanning the fields of view edge to edge, at most ``0.5 / R_max`` rad apart."""
    from nbv_prob_cnn.perception.depth_camera import Intrinsics

    if sensor.vfov_deg is None:
        raise ValueError("sensor: a 3D sensor needs vfov_deg")
    focal = max(sensor.focal_px, sensor.r_max / RAY_SPACING_CELLS)
    half_w = math.tan(math.radians(sensor.hfov_deg) / 2.0)
    half_h = math.tan(math.radians(sensor.vfov_deg) / 2.0)
    nx, ny = max(2, math.ceil(2.0 * half_w * focal) + 1), max(2, math.ceil(2.0 * half_h * focal) + 1)
    return Intrinsics(nx, ny, (nx - 1) / (2.0 * half_w), (ny - 1) / (2.0 * half_h), (nx - 1) / 2.0, (ny - 1) / 2.0)


def ground_truth_points(world: World, meshes: list, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Points spread over ``meshes``, the world's (:data:`POINTS_PER_CELL_FACE` per cell face of
    area), and the unit normal of the triangle of each."""
    points, normals = [], []
    for mesh in meshes:
        vertices, triangles = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
        drawn, index = _surface_points(vertices, triangles, world.resolution, rng)
        corners = vertices[triangles[index]]
        cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        points.append(drawn)
        normals.append(cross / np.maximum(np.linalg.norm(cross, axis=1, keepdims=True), 1e-300))
    return np.concatenate(points), np.concatenate(normals)


def facing(points: np.ndarray, normals: np.ndarray, free: np.ndarray, world: World) -> np.ndarray:
    """Which points face the free space ``free`` (a mask over the world's grid): the cell half,
    one or one and a half cells from the point along its normal, either way, lies in it."""
    origin, shape = np.asarray(world.geometry.origin, dtype=np.float64), np.array(world.shape)
    seen = np.zeros(len(points), dtype=bool)
    for step in (0.5, -0.5, 1.0, -1.0, 1.5, -1.5):
        cells = np.floor((points + step * world.resolution * normals - origin) / world.resolution).astype(np.int64)
        inside = np.all((cells >= 0) & (cells < shape), axis=1)
        seen[inside] |= free[tuple(cells[inside].T)]
    return seen


def distance_to(meshes: list[tuple[np.ndarray, np.ndarray]], points: np.ndarray) -> np.ndarray:
    """The exact distance of each point ``(N, 3)`` to the nearest triangle of ``meshes``
    (``(vertices, triangles)`` pairs; open3d's ``RaycastingScene.compute_distance``, float32)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    for vertices, triangles in meshes:
        if len(triangles):
            scene.add_triangles(
                o3d.core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32)),  # type: ignore[call-overload]
                o3d.core.Tensor(np.ascontiguousarray(triangles, dtype=np.uint32)),  # type: ignore[call-overload]
            )
    query = o3d.core.Tensor(np.ascontiguousarray(points, dtype=np.float32))  # type: ignore[call-overload]
    return scene.compute_distance(query).numpy().astype(np.float64)


def _box(world: World) -> tuple[np.ndarray, np.ndarray]:
    lower = np.asarray(world.geometry.origin, dtype=np.float64)
    return lower - 1e-9, lower + np.asarray(world.shape) * world.resolution + 1e-9


def _surface_points(
    vertices: np.ndarray, triangles: np.ndarray, resolution_m: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """:data:`POINTS_PER_CELL_FACE` points per ``resolution_m²`` of the mesh's area (at most
    :data:`MAX_POINTS`), and their triangles."""
    area = float(triangle_areas(vertices, triangles).sum())
    count = min(MAX_POINTS, math.ceil(POINTS_PER_CELL_FACE * area / resolution_m**2))
    return sample_surface(vertices, triangles, count, rng)


class MeshReconstruction:
    """A TSDF fused from depth images of ``world``'s meshes, one per view taken, and its Chamfer
    distance to them (module docstring).

    Args:
        world: a 3D world with meshes.
        sensor: the voxel sensor of the run (fields of view, ``R_max`` in cells).
        noise: a depth-noise model for the images (its ranges instead of ``R_max``, as
            :func:`~nbv_prob_cnn.sensing.observe.observe` does); None or ideal: exact depth.
        room_margin_m: with ``noise``, walls this far outside the grid.

    The images' noise is seeded by the world's seed.
    """

    def __init__(
        self, world: World, sensor: Sensor, noise: SensorNoise | None = None, room_margin_m: float | None = None
    ) -> None:
        from nbv_prob_cnn.perception.depth_camera import DepthCamera, room_mesh
        from nbv_prob_cnn.perception.tsdf import TsdfIntegrator

        if world.dims != 3:
            raise ValueError(f"world: the Chamfer distance needs a 3D world with meshes, got a {world.dataset} one")
        start = time.perf_counter()
        self.world = world
        meshes = world.triangle_meshes()
        if not meshes:
            raise ValueError(
                f"{world.dataset} world seed {world.seed}: has no meshes (the Chamfer distance needs them)"
            )
        self.truth_meshes = [(np.asarray(m.vertices), np.asarray(m.faces)) for m in meshes]
        self.truth_points, self.truth_normals = ground_truth_points(world, meshes, np.random.default_rng(POINT_SEED))
        self.free: np.ndarray | None = None  # the free space of the first view
        noisy = noise is not None and not noise.is_ideal
        if noisy and room_margin_m is not None:
            lower, upper = _box(world)
            meshes.append(room_mesh(lower - room_margin_m, upper + room_margin_m))
        self.intrinsics = sensor_intrinsics(sensor)
        self.camera = DepthCamera(meshes, self.intrinsics, noise=noise if noisy else None, noise_seed=int(world.seed))
        # the voxel sensor keeps a return within R_max along its ray; a noisy one, its model's ranges
        ray_length = np.linalg.norm(self.intrinsics.pixel_rays(), axis=-1)  # per unit of z-depth
        self.max_range_m = math.inf if noisy else sensor.r_max * world.resolution
        self._max_depth = (self.max_range_m / ray_length).astype(np.float32)
        shape = (world.shape[0], world.shape[1], world.shape[2])
        self.tsdf = TsdfIntegrator(world.geometry.origin, shape, world.resolution, fusion="sparse")
        self.views = 0
        self.seconds = time.perf_counter() - start

    def add_view(self, position_m: np.ndarray, quaternion_xyzw: np.ndarray) -> None:
        """Render the view from ``position_m`` (grid frame, metres) with the optical frame rotated
        by ``quaternion_xyzw`` into the grid frame, and fuse it."""
        start = time.perf_counter()
        if self.free is None:
            self.free = _free_space(self.world, np.asarray(position_m, dtype=np.float64))
        pose = np.eye(4)
        pose[:3, :3] = matrix_from_quaternion(np.asarray(quaternion_xyzw, dtype=np.float64))
        pose[:3, 3] = np.asarray(position_m, dtype=np.float64)
        depth = self.camera.render(pose)
        depth[depth > self._max_depth] = 0.0
        depth_max = float(depth.max()) + 1.0 if math.isinf(self.max_range_m) else self.max_range_m
        self.tsdf.integrate(depth, self.intrinsics, pose, depth_max=depth_max)
        self.views += 1
        self.seconds += time.perf_counter() - start

    def chamfer(self) -> ChamferResult:
        """The Chamfer distance of the TSDF's mesh so far to the visible ground truth (module
        docstring); NaN without a TSDF surface or a visible true surface."""
        start = time.perf_counter()
        vertices, triangles = _tsdf_mesh(self.tsdf)
        points = _surface_points(vertices, triangles, self.world.resolution, np.random.default_rng(POINT_SEED))[0]
        free = self.free if self.free is not None else self.world.ground_truth == 0
        truth = self.truth_points[facing(self.truth_points, self.truth_normals, free, self.world)]
        if len(points) == 0 or len(truth) == 0:
            self.seconds += time.perf_counter() - start
            nan = float("nan")
            return ChamferResult(nan, nan, nan, len(vertices) if len(points) else 0, self.views, self.seconds)
        accuracy = float(distance_to(self.truth_meshes, points).mean())
        completeness = float(distance_to([(vertices, triangles)], truth).mean())
        self.seconds += time.perf_counter() - start
        distance = (accuracy + completeness) / 2.0
        return ChamferResult(distance, accuracy, completeness, len(vertices), self.views, self.seconds)


def _free_space(world: World, position_m: np.ndarray) -> np.ndarray:
    """The free space of the cell holding ``position_m`` (all empty cells when it is not empty)."""
    origin = np.asarray(world.geometry.origin, dtype=np.float64)
    cell = np.clip(np.floor((position_m - origin) / world.resolution).astype(np.int64), 0, np.array(world.shape) - 1)
    if world.ground_truth[tuple(cell)] != 0:
        return world.ground_truth == 0
    return free_space_of(world.ground_truth, cell)


def _tsdf_mesh(tsdf) -> tuple[np.ndarray, np.ndarray]:
    """The TSDF's mesh over every voxel observed at least once (open3d keeps voxels of weight above
    the threshold, so 0.5: one image is enough), empty when it has no surface (open3d raises
    then, for want of vertex colours), in :func:`canonical_order`."""
    try:
        vertices, triangles = tsdf.mesh(weight_threshold=0.5)
    except RuntimeError as exc:
        if "Tensor has shape {0}" not in str(exc):
            raise
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return canonical_order(vertices, triangles)


def canonical_order(vertices: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The same mesh with its vertices sorted by coordinates and its triangles, each started at its
    lowest vertex (orientation kept), sorted: open3d's marching cubes lists them in an order that
    changes from call to call, and the points drawn on a mesh depend on it."""
    order = np.lexsort(vertices.T[::-1])
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(len(order))
    renumbered = rank[triangles]
    first = np.argmin(renumbered, axis=1)
    rotated = renumbered[np.arange(len(renumbered))[:, None], (first[:, None] + np.arange(3)) % 3]
    return vertices[order], rotated[np.lexsort(rotated.T[::-1])]
