"""Surfaces out of a fused grid: the occupied cells as a point cloud, meshes and clouds as PLY files,
and a picture of a mesh (matplotlib, no display needed).

The mesh itself is :meth:`~nbv_prob_cnn.perception.TsdfIntegrator.mesh` (marching cubes of the TSDF).
PLY files are binary little-endian: ``float32`` vertices ``x y z`` (world metres) and, for a mesh,
``int32`` triangles; any PLY reader (open3d, trimesh, MeshLab, CloudCompare, RViz plugins) opens them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nbv_prob_cnn.basics.grid import OCCUPIED

__all__ = ["decimate", "occupied_centres", "render_mesh_png", "write_ply"]


def occupied_centres(grid: np.ndarray, origin_m: np.ndarray, voxel_size_m: float) -> np.ndarray:
    """``(N, 3)`` world coordinates (m) of the centres of the occupied cells of a ternary grid."""
    ijk = np.argwhere(np.asarray(grid) == OCCUPIED)
    return np.asarray(origin_m, dtype=np.float64) + (ijk + 0.5) * float(voxel_size_m)


def write_ply(path: str | Path, vertices: np.ndarray, triangles: np.ndarray | None = None) -> Path:
    """Write points (and triangles, for a mesh) to a binary little-endian PLY file; return its path.

    Raises:
        ValueError: vertices not ``(N, 3)`` finite, or triangles not ``(F, 3)`` indices of them.
    """
    points = np.asarray(vertices, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or not np.all(np.isfinite(points)):
        raise ValueError(f"ply: vertices must be finite (N, 3), got shape {points.shape}")
    faces = None if triangles is None else np.asarray(triangles, dtype=np.int64)
    if faces is not None and (
        faces.ndim != 2 or faces.shape[1] != 3 or (faces.size and not (faces.min() >= 0 and faces.max() < len(points)))
    ):
        raise ValueError(f"ply: triangles must be (F, 3) indices below {len(points)}, got shape {faces.shape}")
    header = ["ply", "format binary_little_endian 1.0", "comment nbv_prob_cnn: world metres"]
    header += [f"element vertex {len(points)}", "property float x", "property float y", "property float z"]
    if faces is not None:
        header += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
    header.append("end_header")
    path = Path(path)
    with path.open("wb") as out:
        out.write(("\n".join(header) + "\n").encode("ascii"))
        out.write(np.ascontiguousarray(points, dtype="<f4").tobytes())
        if faces is not None:
            records = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
            records["n"] = 3
            records["v"] = faces
            out.write(records.tobytes())
    return path


def decimate(vertices: np.ndarray, triangles: np.ndarray, max_triangles: int) -> tuple[np.ndarray, np.ndarray]:
    """A coarser mesh of at most ``max_triangles`` triangles: open3d's vertex clustering on cells grown
    until it fits (each cell's vertices merged into their mean)."""
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles))
    extent = float(np.max(vertices.max(axis=0) - vertices.min(axis=0)))
    cell = extent / 400.0
    while True:
        coarse = mesh.simplify_vertex_clustering(voxel_size=cell)
        if len(coarse.triangles) <= max_triangles:
            return np.asarray(coarse.vertices), np.asarray(coarse.triangles, dtype=np.int64)
        cell *= 1.25


def render_mesh_png(
    path: str | Path,
    vertices: np.ndarray,
    triangles: np.ndarray,
    title: str = "",
    max_triangles: int = 60_000,
    elevation_deg: float = 35.0,
    azimuth_deg: float = -60.0,
) -> Path:
    """A shaded picture of a mesh (matplotlib ``plot_trisurf``, offscreen), decimated to at most
    ``max_triangles`` triangles (:func:`decimate`); colour = height (z)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    vertices = np.asarray(vertices, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.int64)
    if len(triangles) == 0:
        raise ValueError("render: the mesh has no triangles")
    if len(triangles) > max_triangles:
        vertices, triangles = decimate(vertices, triangles, max_triangles)
    fig = plt.figure(figsize=(9, 6.5), dpi=110)
    ax = fig.add_subplot(projection="3d")
    surface = ax.plot_trisurf(
        vertices[:, 0], vertices[:, 1], vertices[:, 2], triangles=triangles, cmap="viridis", linewidth=0.0,
        antialiased=False, shade=True,
    )  # fmt: skip
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    ax.set_box_aspect(tuple(np.maximum(hi - lo, 1e-6)))
    ax.view_init(elev=elevation_deg, azim=azimuth_deg)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    fig.colorbar(surface, ax=ax, shrink=0.6, pad=0.12, label="height z (m)")
    if title:
        ax.set_title(title)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path)
    plt.close(fig)
    return path
