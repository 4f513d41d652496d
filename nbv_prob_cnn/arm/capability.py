"""Capability map: which of the 52 view orientations the camera reaches at which grid position.

The map is a 6-D table ``reachable[i, j, k, v]`` on a lattice of grid cells every ``stride``
cells (node ``(i, j, k)`` sits at the centre of cell ``stride · (i, j, k)``; the last node may lie
just beyond the grid) × the planning orientations (``camera.orientations(3)``). A node/orientation
is reachable when the batched IK (:mod:`nbv_prob_cnn.arm.ik`) converges within the joint limits
from the robot's reference configuration or from one of ``random_rounds`` random seeds. Collision
is not part of the map (it depends on the grid); nodes farther from the first joint than the
chain's total length are unreachable without IK.

A query cell takes the OR of the eight nodes around it, so the map errs towards "reachable"
(false positives are removed by the exact check after the gain, false negatives lose views; tests
count them against exact IK). The map also keeps each reachable entry's IK solution
(``configurations``): the warm seed of the exact IK of a view near that node
(:meth:`CapabilityMap.seed_configurations`).

Maps are cached in ``<cache>/arm/capability_<key>.npz``, keyed by a hash of the robot (URDF, base
pose, camera mount), the grid geometry, the stride, the orientations, the solver settings and the
file format's version; a changed key builds a new map.
"""

from __future__ import annotations

import hashlib
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from nbv_prob_cnn.arm.ik import IkSettings, solve_batch
from nbv_prob_cnn.arm.kinematics import CameraChain
from nbv_prob_cnn.arm.robot import RobotModel, arm_cache_dir
from nbv_prob_cnn.basics.camera import matrix_from_quaternion, orientations
from nbv_prob_cnn.basics.geometry import GridGeometry

MAP_VERSION = 2  # 2: the IK solutions (configurations) are stored with the table
#: Targets solved per IK batch while building (bounds memory).
BUILD_BATCH = 20_000
#: Solver settings of the build: fewer iterations per round than a single solve (most reachable
#: targets converge in < 30 from the reference; misses are what the random rounds are for).
MAP_IK = IkSettings(max_iterations=60)


class UnreachableWorkspaceError(ValueError):
    """The arm reaches no view of the grid (empty capability map)."""


@dataclass
class CapabilityMap:
    """Reachability of (lattice node, orientation) pairs.

    Attributes:
        reachable: ``(I, J, K, V)`` bool.
        stride: lattice spacing in cells.
        geometry: the grid the lattice covers.
        build_seconds: time the build took (0 when loaded from the cache).
        configurations: optional ``(I, J, K, V, n)`` float32 chain configurations that reach
            each reachable entry (NaN elsewhere).
    """

    reachable: np.ndarray
    stride: int
    geometry: GridGeometry
    build_seconds: float = 0.0
    configurations: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not np.any(self.reachable):
            raise UnreachableWorkspaceError(
                "capability map: the arm reaches no camera pose in the grid; check the base pose "
                "(world_from_base), the camera mount and the grid placement"
            )

    @property
    def reachable_fraction(self) -> float:
        return float(self.reachable.mean())

    def views_at(self, cells: np.ndarray, strict: bool = False) -> np.ndarray:
        """``(N, V)`` bool: orientations possibly reachable at grid cells ``(N, 3)``: the OR of
        the (up to eight) lattice nodes around each cell (``strict``: the AND, fewer false
        positives, more false negatives); a cell on a node plane along an axis only looks at
        that plane. Cells outside the grid (negative indices) or beyond the lattice see nothing."""
        cells = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
        slot = 2 * (cells // self.stride) + ((cells % self.stride) != 0)
        table = self._slot_table(strict)
        inside = np.all((slot >= 0) & (slot < np.array(table.shape[:3])), axis=1)
        out = np.zeros((cells.shape[0], table.shape[3]), dtype=bool)
        s = slot[inside]
        out[inside] = table[s[:, 0], s[:, 1], s[:, 2]]
        return out

    def _slot_table(self, strict: bool) -> np.ndarray:
        """Lookup per slot ``2 · node + between`` along each axis (even: on a node plane, odd:
        between two nodes), reduced over the nodes around it once, so a query is one gather."""
        cache = self.__dict__.setdefault("_slot_tables", {})
        if strict not in cache:
            nodes = np.array(self.reachable.shape[:3])
            slots = np.stack(np.meshgrid(*[np.arange(2 * n) for n in nodes], indexing="ij"), -1).reshape(-1, 3)
            base, between = slots // 2, slots % 2
            table = np.full((slots.shape[0], self.reachable.shape[3]), strict, dtype=bool)
            for corner in np.ndindex(2, 2, 2):
                node = base + np.array(corner) * between
                valid = np.all(node < nodes, axis=1)
                node = np.minimum(node, nodes - 1)
                at_node = self.reachable[node[:, 0], node[:, 1], node[:, 2]] & valid[:, None]
                table = table & at_node if strict else table | at_node
            cache[strict] = table.reshape(*(2 * nodes), -1)
        return cache[strict]

    def seed_configurations(self, cells: np.ndarray, views: np.ndarray) -> np.ndarray | None:
        """``(N, n)`` chain configurations stored at the lattice node nearest to each cell for
        its orientation (NaN rows where that node does not reach it); None without stored ones."""
        if self.configurations is None:
            return None
        cells = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
        nodes = np.array(self.reachable.shape[:3])
        node = np.clip(np.rint(cells / self.stride).astype(np.int64), 0, nodes - 1)
        views = np.asarray(views, dtype=np.int64).ravel()
        return self.configurations[node[:, 0], node[:, 1], node[:, 2], views].astype(np.float64)

    def strict_views_at(self, cells: np.ndarray) -> np.ndarray:
        """:meth:`views_at` with ``strict=True``."""
        return self.views_at(cells, strict=True)

    def origin_filter(self, origins: np.ndarray) -> np.ndarray:
        """The origins where at least one orientation is possibly reachable (for ``GainPlanner.rank``)."""
        if origins.shape[0] == 0:
            return origins
        return origins[self.views_at(origins).any(axis=1)]


def node_cells(geometry: GridGeometry, stride: int) -> np.ndarray:
    """Cell coordinates ``(I, J, K, 3)`` of the lattice nodes (covering the whole grid)."""
    counts = [int(np.ceil((n - 1) / stride)) + 1 for n in geometry.shape]
    axes = [np.arange(c) * stride for c in counts]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)


def view_rotations() -> np.ndarray:
    """``(V, 3, 3)`` rotations of the planning orientations."""
    return np.stack([matrix_from_quaternion(q) for q in orientations(3)])


def chain_reach(chain: CameraChain) -> tuple[np.ndarray, float]:
    """Origin of the first chain joint (world) and an upper bound of the camera's distance from it."""
    first = chain.placements[0][:3, 3]
    lengths = [np.linalg.norm(p[:3, 3]) for p in chain.placements[1:]] + [np.linalg.norm(chain.tip[:3, 3])]
    prismatic_travel = np.abs(np.maximum(np.abs(chain.lower), np.abs(chain.upper)))[chain.prismatic].sum()
    return first, float(sum(lengths) + prismatic_travel)


def capability_key(robot: RobotModel, geometry: GridGeometry, stride: int, settings: IkSettings, rounds: int) -> str:
    """The cache key of a map: robot (URDF, base pose, camera mount), grid placement (to 1 µm)
    and shape, stride, IK settings and rounds, the format version and the orientations."""
    digest = hashlib.sha256(robot.config.cache_key().encode())
    # rounded to 1 µm: a grid message carries float32 sizes, so the nodes' grid and the core's
    # grid of the same box differ in the last bits and would build a map each
    placement = tuple(round(float(v), 6) for v in (*geometry.origin, geometry.resolution))
    digest.update(repr((placement, tuple(int(n) for n in geometry.shape), int(stride))).encode())
    digest.update(repr((settings, rounds, MAP_VERSION)).encode())
    digest.update(np.round(orientations(3), 9).tobytes())
    return digest.hexdigest()[:20]


def build_capability_map(
    robot: RobotModel,
    geometry: GridGeometry,
    stride: int,
    settings: IkSettings = MAP_IK,
    random_rounds: int = 2,
    seed: int = 0,
    progress: bool = True,
) -> CapabilityMap:
    """Solve IK for every lattice node × orientation (see the module doc).

    Raises:
        ValueError: stride < 1 or a 2D grid.
        UnreachableWorkspaceError: nothing is reachable.
    """
    if stride < 1:
        raise ValueError(f"stride: expected >= 1 cell, got {stride}")
    if geometry.dims != 3:
        raise ValueError("capability map: needs a 3D grid")
    start = time.perf_counter()
    chain = CameraChain(robot)
    rng = np.random.default_rng(seed)
    cells = node_cells(geometry, stride)
    centres = geometry.cell_centre(cells.reshape(-1, 3))
    rotations = view_rotations()
    n_nodes, n_views = centres.shape[0], rotations.shape[0]
    first, reach = chain_reach(chain)
    near = np.nonzero(np.linalg.norm(centres - first, axis=1) <= reach)[0]
    pairs = np.stack(np.meshgrid(near, np.arange(n_views), indexing="ij"), axis=-1).reshape(-1, 2)
    reachable = np.zeros(n_nodes * n_views, dtype=bool)
    configurations = np.full((n_nodes * n_views, chain.n), np.nan, dtype=np.float32)
    seed_q = robot.reference_q[chain.q_index]
    batches = range(0, pairs.shape[0], BUILD_BATCH)
    for begin in tqdm(batches, desc="capability map", unit="batch", disable=not progress):
        chunk = pairs[begin : begin + BUILD_BATCH]
        targets = np.broadcast_to(np.eye(4), (chunk.shape[0], 4, 4)).copy()
        targets[:, :3, :3] = rotations[chunk[:, 1]]
        targets[:, :3, 3] = centres[chunk[:, 0]]
        todo = np.arange(chunk.shape[0])
        seeds = np.broadcast_to(seed_q, (todo.size, chain.n))
        for round_ in range(random_rounds + 1):
            if round_ > 0:
                seeds = rng.uniform(chain.lower, chain.upper, size=(todo.size, chain.n))
            q, ok = solve_batch(chain, targets[todo], seeds, settings)
            entries = chunk[todo[ok], 0] * n_views + chunk[todo[ok], 1]
            reachable[entries] = True
            configurations[entries] = q[ok]
            todo = todo[~ok]
            if todo.size == 0:
                break
    table = reachable.reshape(cells.shape[:3] + (n_views,))
    stored = configurations.reshape(cells.shape[:3] + (n_views, chain.n))
    return CapabilityMap(table, int(stride), geometry, time.perf_counter() - start, stored)


def capability_map_path(key: str) -> Path:
    return arm_cache_dir() / f"capability_{key}.npz"


def load_or_build_capability_map(
    robot: RobotModel,
    geometry: GridGeometry,
    stride: int,
    settings: IkSettings = MAP_IK,
    random_rounds: int = 2,
    progress: bool = True,
) -> CapabilityMap:
    """The cached map of this robot/grid/stride (see :func:`capability_key`), built and cached
    when there is none (or the file cannot be read)."""
    path = capability_map_path(capability_key(robot, geometry, stride, settings, random_rounds))
    if path.is_file():
        try:
            return load_capability_map(path, geometry)
        except (OSError, KeyError, ValueError):
            pass  # a damaged or foreign file: build again and replace it
    capability = build_capability_map(robot, geometry, stride, settings, random_rounds, progress=progress)
    save_capability_map(capability, path)
    return capability


def save_capability_map(capability: CapabilityMap, path: Path) -> None:
    """Write a map atomically (a temporary file renamed into place)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + f".tmp{os.getpid()}.npz")
    arrays: dict[str, np.ndarray] = {"reachable": capability.reachable, "stride": np.array(capability.stride)}
    if capability.configurations is not None:
        arrays["configurations"] = capability.configurations
    np.savez_compressed(tmp, **arrays)  # type: ignore[arg-type]
    tmp.replace(path)


def load_capability_map(path: Path, geometry: GridGeometry) -> CapabilityMap:
    """A map written by :func:`save_capability_map` for grids of ``geometry``.

    Raises:
        ValueError: a table whose lattice does not cover ``geometry``.
    """
    with np.load(path) as data:
        reachable = data["reachable"].astype(bool)
        stride = int(data["stride"])
        configurations = data["configurations"] if "configurations" in data.files else None
    expected = node_cells(geometry, stride).shape[:3]
    if reachable.shape[:3] != expected:
        raise ValueError(f"capability map {path}: lattice {reachable.shape[:3]}, expected {expected} for this grid")
    return CapabilityMap(reachable, stride, geometry, configurations=configurations)
