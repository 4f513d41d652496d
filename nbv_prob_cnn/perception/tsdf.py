"""TSDF integration of depth images, and its ternary occupancy grid.

Cells follow the World convention: cell ``[i, j, k]`` spans
``origin + ([i, j, k] + [0, 1)) * voxel_size``. Internally an open3d
``t.geometry.VoxelBlockGrid`` samples the TSDF at integer multiples of the voxel size, so the
integrator works in a "volume frame" shifted by ``origin + voxel_size/2``: open3d voxel
``[i, j, k]`` is sampled exactly at the centre of grid cell ``[i, j, k]``.

Two ways to fuse (``fusion``), with the same cells:
    * ``"sparse"`` (default): per frame only the blocks its rays cross are allocated and updated
      (:func:`~nbv_prob_cnn.perception.frustum_blocks.frustum_blocks`: the surface band and the
      free space in front of each return), so the cost follows what the camera sees, not the box.
      The box may be left open (``shape_cells=None``): the grid then spans the cells observed so
      far (it grows as the scene is seen).
    * ``"dense"``: every block of the box is allocated up front and every integration updates all
      of them (the cost follows the box).
Open3d only writes voxels of blocks it is given, and the sparse mode gives it a superset of the
blocks holding a voxel the frame updates, so both modes label every cell alike (tested).
Per pixel, open3d's projective TSDF: ``sdf = depth(pixel of the cell centre) - z(cell centre)``;
cells with ``sdf < -trunc`` are left untouched, others get ``clamp(sdf, ., trunc)/trunc``
averaged with weight 1 per frame.

Ternary extraction (the values of docs/method.md#grids):
    * weight 0 (never observed)                         -> UNKNOWN (-1)
    * ``tsdf * trunc > empty_margin`` (in front of the surface by more than the margin) -> EMPTY (0)
    * otherwise (near the surface, or behind it within the truncation) -> OCCUPIED (1)

Pixels with depth 0, NaN, inf, negative or beyond ``depth_max`` are "no return" and observe
nothing (no free-space carving along them).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nbv_prob_cnn.basics.camera import DATASETS
from nbv_prob_cnn.basics.grid import EMPTY, OCCUPIED, UNKNOWN
from nbv_prob_cnn.perception.depth_camera import Intrinsics, check_pose
from nbv_prob_cnn.perception.frustum_blocks import frustum_blocks

__all__ = [
    "DEFAULT_EMPTY_MARGIN_VOXELS",
    "DEFAULT_ORIGIN_M",
    "DEFAULT_SHAPE",
    "DEFAULT_TRUNC_VOXELS",
    "DEFAULT_VOXEL_M",
    "FUSION_MODES",
    "TsdfIntegrator",
    "depth_to_metres",
    "load_grid",
    "save_grid",
]

DEFAULT_SHAPE: tuple[int, int, int] = tuple(DATASETS["3dt"].shape)  # type: ignore[assignment]
DEFAULT_VOXEL_M: float = DATASETS["3dt"].resolution_m
DEFAULT_ORIGIN_M: tuple[float, float, float] = (0.0, 0.0, 0.0)  # as the 3DT generator
DEFAULT_TRUNC_VOXELS: float = 3.0
# A cell holding a surface has its centre up to sqrt(3)/2 voxel from it (Euclidean), more along
# the viewing ray at oblique incidence; 1.5 voxels keeps >= 90 % of seen surface cells occupied
# with mild sensor noise (see test_perception.py and docs) at the cost of ~1 voxel of "thickening".
DEFAULT_EMPTY_MARGIN_VOXELS: float = 1.5
FUSION_MODES = ("sparse", "dense")
#: Voxels per block edge by fusion mode: small blocks fit the frustum and the surface band closer
#: (fewer voxels updated per frame: 0.68 M against 1.08 M at 2 cm on the kitchen recording).
DEFAULT_BLOCK_RESOLUTION = {"sparse": 8, "dense": 16}
#: Blocks of the hash map of an open (unbounded) sparse grid at the start; it grows by
#: :data:`BLOCK_GROWTH` when a frame needs more.
INITIAL_BLOCKS = 16384
BLOCK_GROWTH = 2.0
#: Blocks read at a time when the sparse grid is read out (bounds the read-out's extra memory).
READ_CHUNK_BLOCKS = 4096


def depth_to_metres(depth: np.ndarray, depth_scale: float | None = None) -> np.ndarray:
    """Convert a depth image to ``float32`` metres with every "no return" pixel set to 0.

    Args:
        depth: ``float`` metres, or ``uint16`` millimetres (16UC1).
        depth_scale: units per metre; default 1000 for integer images and 1 for float images.

    Raises:
        ValueError: not a 2D array, or an unsupported dtype.
    """
    arr = np.asarray(depth)
    if arr.ndim != 2:
        raise ValueError(f"depth: expected a 2D (H, W) image, got shape {arr.shape}")
    if arr.dtype == np.uint16 or np.issubdtype(arr.dtype, np.integer):
        scale = 1000.0 if depth_scale is None else float(depth_scale)
        metres = arr.astype(np.float32) / np.float32(scale)
    elif np.issubdtype(arr.dtype, np.floating):
        scale = 1.0 if depth_scale is None else float(depth_scale)
        metres = arr.astype(np.float32, copy=True)
        if scale != 1.0:
            metres /= np.float32(scale)
    else:
        raise ValueError(f"depth: expected a float (metres) or uint16 (millimetres) image, got dtype {arr.dtype}")
    metres[~(np.isfinite(metres) & (metres > 0))] = 0.0
    return metres


@dataclass
class IntegrationStats:
    """Running counters of an integrator."""

    frames: int = 0
    seconds: float = 0.0
    blocks_updated: int = 0  # sum over the frames of the blocks handed to open3d


class TsdfIntegrator:
    """TSDF fusion of posed depth images, with a ternary occupancy read-out.

    Args:
        origin_m: world coordinates of the corner of cell 0 (World convention); with an open box,
            the anchor of the cell lattice.
        shape_cells: ``(nx, ny, nz)`` cells of the box, or ``None`` (sparse fusion only): no box,
            the grid spans the cells observed so far (:meth:`grid_box`).
        voxel_size_m: cell edge (m).
        trunc_voxels: TSDF truncation distance, in voxels.
        empty_margin_voxels: a cell is EMPTY when its (averaged, projective) signed distance is
            more than this many voxels in front of the surface; otherwise an observed cell is
            OCCUPIED. Must be smaller than ``trunc_voxels``.
        block_resolution: voxels per block edge of the open3d grid (default
            :data:`DEFAULT_BLOCK_RESOLUTION` of the mode).
        device: open3d device string (``"CPU:0"``, ``"CUDA:0"``).
        refine_pose_icp: when True, each frame after the first has its pose refined by
            frame-to-model point-to-plane odometry (the depth image against a ray cast of the
            current TSDF from the given pose) before it is integrated; ``integrate`` returns the
            pose used. Off by default: with simulated or motion-capture poses the given pose is
            better than the refinement (measured: a 1.4 cm / 1 deg pose error drops to ~3-8 mm /
            <= 0.5 deg; ~1 s per 640x480 frame on a 2-core CPU). A frame whose odometry fails or
            has fitness < 0.3 keeps its given pose.
        fusion: ``"sparse"`` (only the blocks each frame's rays cross) or ``"dense"`` (every block
            of the box, every frame); same cells (module docstring).
    """

    def __init__(
        self,
        origin_m: np.ndarray | tuple[float, float, float] = DEFAULT_ORIGIN_M,
        shape_cells: tuple[int, int, int] | None = DEFAULT_SHAPE,
        voxel_size_m: float = DEFAULT_VOXEL_M,
        trunc_voxels: float = DEFAULT_TRUNC_VOXELS,
        empty_margin_voxels: float = DEFAULT_EMPTY_MARGIN_VOXELS,
        block_resolution: int | None = None,
        device: str = "CPU:0",
        refine_pose_icp: bool = False,
        fusion: str = "sparse",
    ) -> None:
        import open3d as o3d
        import open3d.core as o3c

        if fusion not in FUSION_MODES:
            raise ValueError(f"fusion: expected one of {FUSION_MODES}, got {fusion!r}")
        self.origin = np.asarray(origin_m, dtype=np.float64).reshape(3)
        self.shape: tuple[int, int, int] | None = None
        if shape_cells is not None:
            shape = tuple(int(s) for s in shape_cells)
            if len(shape) != 3 or min(shape) <= 0:
                raise ValueError(f"shape_cells: expected three positive sizes, got {shape_cells}")
            self.shape = (shape[0], shape[1], shape[2])
        elif fusion == "dense":
            raise ValueError("shape_cells: dense fusion needs a box (shape_cells=None is sparse only)")
        if not np.all(np.isfinite(self.origin)):
            raise ValueError(f"origin_m: must be finite, got {self.origin.tolist()}")
        if not voxel_size_m > 0:
            raise ValueError(f"voxel_size_m: must be positive, got {voxel_size_m}")
        if not 0.0 <= empty_margin_voxels < trunc_voxels:
            raise ValueError(
                f"empty_margin_voxels ({empty_margin_voxels}) must lie in [0, trunc_voxels={trunc_voxels})"
            )
        if block_resolution is None:
            block_resolution = DEFAULT_BLOCK_RESOLUTION[fusion]
        if block_resolution <= 0:
            raise ValueError(f"block_resolution: must be positive, got {block_resolution}")
        self.fusion = fusion
        self.voxel_size = float(voxel_size_m)
        self.trunc_voxels = float(trunc_voxels)
        self.empty_margin_voxels = float(empty_margin_voxels)
        self.block_resolution = int(block_resolution)
        self.refine_pose_icp = bool(refine_pose_icp)
        self.device = o3c.Device(device)
        self.stats = IntegrationStats()
        self.last_pose: np.ndarray | None = None
        self._o3d = o3d
        self._o3c = o3c
        self._blocks: tuple[int, int, int] | None = None
        if self.shape is not None:
            b = self.block_resolution
            self._blocks = (-(-self.shape[0] // b), -(-self.shape[1] // b), -(-self.shape[2] // b))
        # volume frame = world shifted so that open3d voxel i sits at the centre of cell i
        self._volume_from_world = np.eye(4)
        self._volume_from_world[:3, 3] = -(self.origin + 0.5 * self.voxel_size)
        self._allocate()

    @property
    def bounded(self) -> bool:
        """Whether the grid has a fixed box (``shape_cells`` given)."""
        return self.shape is not None

    # ------------------------------------------------------------------ set-up
    def _allocate(self) -> None:
        """Create the voxel block grid; dense: activate every block of the box."""
        o3d, o3c = self._o3d, self._o3c
        box_blocks = None if self._blocks is None else int(np.prod(self._blocks))
        if self.fusion == "dense":
            # twice the blocks of the box: integrate() re-activates all of them, and open3d rehashes
            # (a full copy) whenever size + requested > capacity
            assert box_blocks is not None
            n_blocks = 2 * box_blocks
        else:
            # a box holds at most its own blocks (+ room for open3d's activation of a frame's)
            n_blocks = INITIAL_BLOCKS if box_blocks is None else min(INITIAL_BLOCKS, 2 * box_blocks)
        self._vbg = o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight"),
            attr_dtypes=(o3c.float32, o3c.float32),
            attr_channels=((1), (1)),
            voxel_size=self.voxel_size,
            block_resolution=self.block_resolution,
            block_count=n_blocks,
            device=self.device,
        )
        self._block_coords = None
        if self.fusion == "dense":
            assert self._blocks is not None
            coords = np.stack(np.meshgrid(*[np.arange(n) for n in self._blocks], indexing="ij"), axis=-1)
            self._block_coords = o3c.Tensor(coords.reshape(-1, 3).astype(np.int32), device=self.device)
            self._vbg.hashmap().activate(self._block_coords)
        # blocks are not zero-initialised when activated: every slot starts zero (and free slots are
        # zeroed again after each growth), so a block takes a zero slot when a frame first touches it
        self._zero_slots(None)

    def _zero_slots(self, keep: np.ndarray | None) -> None:
        """Zero the tsdf and weight of every buffer slot but ``keep`` (all of them for ``None``)."""
        o3c = self._o3c
        capacity = int(self._vbg.hashmap().capacity())
        free = np.ones(capacity, dtype=bool)
        if keep is not None:
            free[keep] = False
        for name in ("tsdf", "weight"):
            if self.device.get_type() == o3c.Device.DeviceType.CPU:
                self._vbg.attribute(name).numpy()[free] = 0.0  # numpy shares the buffer
            else:
                self._vbg.attribute(name)[o3c.Tensor(free, device=self.device)] = 0.0

    def reset(self) -> None:
        """Forget everything integrated so far (every cell UNKNOWN again; sparse: blocks freed)."""
        self._allocate()
        self.stats = IntegrationStats()
        self.last_pose = None

    @property
    def allocated_blocks(self) -> int:
        """Blocks of the voxel block grid in use."""
        return int(self._vbg.hashmap().size())

    def _make_room(self, n_blocks: int) -> None:
        """Sparse: grow the hash map ahead of open3d's activation of a frame's ``n_blocks`` blocks in
        ``integrate`` (it rehashes, a full copy, when size + requested > capacity, even for blocks it
        holds already), then zero the free slots of the new buffer."""
        hashmap = self._vbg.hashmap()
        need = int(hashmap.size()) + n_blocks
        if need > int(hashmap.capacity()):
            hashmap.reserve(max(need, int(BLOCK_GROWTH * hashmap.capacity())))
            self._zero_slots(hashmap.active_buf_indices().cpu().numpy().astype(np.int64))

    # ------------------------------------------------------------- integration
    def _o3d_intrinsics(self, intrinsics: Intrinsics) -> np.ndarray:
        # open3d truncates projected pixel coordinates (pixel u covers [u, u+1)); shifting the
        # principal point by half a pixel makes that a round-to-nearest on ROS pixel centres.
        k = intrinsics.matrix
        k[0, 2] += 0.5
        k[1, 2] += 0.5
        return k

    def integrate(
        self,
        depth: np.ndarray,
        intrinsics: Intrinsics,
        pose_world_from_optical: np.ndarray,
        depth_max: float = 3.0,
        depth_scale: float | None = None,
    ) -> np.ndarray:
        """Fuse one depth image.

        Args:
            depth: ``float32 (H, W)`` metres or ``uint16`` millimetres; 0/NaN = no return.
            intrinsics: pinhole parameters of the image.
            pose_world_from_optical: 4×4 camera pose (REP-103 optical frame).
            depth_max: returns farther than this (m) are treated as no return.
            depth_scale: units per metre if not the default (1000 for uint16, 1 for float).

        Returns:
            The pose actually used (refined when ``refine_pose_icp`` is on).

        Raises:
            ValueError: bad pose, bad image dtype, or image shape not matching the intrinsics.
        """
        o3d, o3c = self._o3d, self._o3c
        t0 = time.perf_counter()
        pose = check_pose(pose_world_from_optical, "pose_world_from_optical")
        metres = depth_to_metres(depth, depth_scale)
        if metres.shape != intrinsics.shape:
            raise ValueError(f"depth: shape {metres.shape} does not match the intrinsics {intrinsics.shape}")
        image = o3d.t.geometry.Image(o3c.Tensor(metres, device=self.device))
        k = self._o3d_intrinsics(intrinsics)
        if self.refine_pose_icp and self.stats.frames > 0:
            pose = self._refine_pose(image, intrinsics, pose, depth_max)
        extrinsic = np.linalg.inv(self._volume_from_world @ pose)  # optical_from_volume
        if self._block_coords is not None:  # dense: every block of the box
            blocks, n_blocks = self._block_coords, int(self._block_coords.shape[0])
        else:
            coords = frustum_blocks(
                metres, k, extrinsic, self.voxel_size, self.block_resolution,
                self.trunc_voxels * self.voxel_size, float(depth_max), self._blocks,
            )  # fmt: skip
            n_blocks = len(coords)
            self._make_room(n_blocks)
            blocks = o3c.Tensor(coords, device=self.device)
        if n_blocks:
            self._vbg.integrate(
                blocks, image, o3c.Tensor(k), o3c.Tensor(extrinsic), 1.0, float(depth_max), self.trunc_voxels
            )
        self.stats.blocks_updated += n_blocks
        self.stats.frames += 1
        self.stats.seconds += time.perf_counter() - t0
        self.last_pose = pose
        return pose

    def _refine_pose(self, image: object, intrinsics: Intrinsics, pose: np.ndarray, depth_max: float) -> np.ndarray:
        """Frame-to-model point-to-plane odometry from the given pose (see class docstring)."""
        o3d, o3c = self._o3d, self._o3c
        k = o3c.Tensor(intrinsics.matrix)  # ray casting and odometry unproject pixel centres at integers
        # open3d's ray caster reads voxel floor(x / voxel) while integration samples voxel i at
        # i * voxel: shifting the query frame by half a voxel makes the read nearest-sample
        # (removes a ~1 voxel depth bias of the rendered model)
        half = np.eye(4)
        half[:3, 3] = 0.5 * self.voxel_size
        extrinsic = o3c.Tensor(np.linalg.inv(half @ self._volume_from_world @ pose))
        rendering = self._vbg.ray_cast(
            self._active_block_coords(),
            k,
            extrinsic,
            intrinsics.width,
            intrinsics.height,
            render_attributes=["depth"],
            depth_scale=1.0,
            depth_min=0.01,
            depth_max=float(depth_max),
            weight_threshold=1.0,
            trunc_voxel_multiplier=self.trunc_voxels,
        )
        model_depth = rendering["depth"].to(o3c.float32)
        if int((model_depth.cpu().numpy() > 0).sum()) < 100:
            return pose  # nothing to align against
        blank = o3c.Tensor(np.zeros((*intrinsics.shape, 3), dtype=np.float32), device=self.device)
        source = o3d.t.geometry.RGBDImage(o3d.t.geometry.Image(blank), image)
        target = o3d.t.geometry.RGBDImage(o3d.t.geometry.Image(blank), o3d.t.geometry.Image(model_depth))
        criteria = [o3d.t.pipelines.odometry.OdometryConvergenceCriteria(n) for n in (10, 10, 10)]
        try:
            result = o3d.t.pipelines.odometry.rgbd_odometry_multi_scale(
                source,
                target,
                k,
                o3c.Tensor(np.eye(4)),
                1.0,
                float(depth_max),
                criteria,
                o3d.t.pipelines.odometry.Method.PointToPlane,
            )
        except RuntimeError:
            return pose  # odometry failed (degenerate geometry): keep the given pose
        if result.fitness < 0.3:
            return pose
        source_to_target = result.transformation.cpu().numpy().astype(np.float64)
        # source = current camera, target = the model rendered from the given pose
        return pose @ source_to_target

    # --------------------------------------------------------------- read-out
    def _active_block_coords(self) -> object:
        """open3d tensor of the coordinates of every allocated block."""
        if self._block_coords is not None:
            return self._block_coords
        hashmap = self._vbg.hashmap()
        return hashmap.key_tensor()[hashmap.active_buf_indices().to(self._o3c.int64)]

    def _active(self) -> tuple[np.ndarray, np.ndarray]:
        """``(block coordinates int64 (n, 3), buffer slots int64 (n,))`` of the allocated blocks."""
        hashmap = self._vbg.hashmap()
        slots = hashmap.active_buf_indices().to(self._o3c.int64)
        keys = hashmap.key_tensor()[slots].cpu().numpy().astype(np.int64)
        return keys, slots.cpu().numpy()

    def _chunks(self) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """``(block coordinates, tsdf, weight)`` of the allocated blocks, a chunk at a time; voxel
        arrays ``(n, r, r, r)`` in open3d's voxel order ``[z, y, x]``."""
        keys, slots = self._active()
        tsdf = self._vbg.attribute("tsdf").cpu().numpy()  # (capacity, r, r, r, 1), shared with open3d on CPU
        weight = self._vbg.attribute("weight").cpu().numpy()
        for i in range(0, len(slots), READ_CHUNK_BLOCKS):
            chunk = slots[i : i + READ_CHUNK_BLOCKS]
            yield keys[i : i + READ_CHUNK_BLOCKS], tsdf[chunk, ..., 0], weight[chunk, ..., 0]

    def grid_box(self) -> tuple[np.ndarray, tuple[int, int, int]]:
        """``(origin (3,), shape)`` of the grid :meth:`ternary` returns: the box, or for an open
        grid the smallest box of the cells observed so far (one cell at ``origin_m`` when none)."""
        if self.shape is not None:
            return self.origin.copy(), self.shape
        lo, hi = self._observed_voxels()
        return self.origin + lo * self.voxel_size, (
            int(hi[0] - lo[0] + 1),
            int(hi[1] - lo[1] + 1),
            int(hi[2] - lo[2] + 1),
        )

    def _observed_voxels(self) -> tuple[np.ndarray, np.ndarray]:
        """Smallest and largest voxel index (int64 (3,)) with a weight, over all axes."""
        r = self.block_resolution
        lo = np.full(3, np.iinfo(np.int64).max)
        hi = np.full(3, np.iinfo(np.int64).min)
        for keys, _, weight in self._chunks():
            seen = np.asarray(weight > 0)  # (n, z, y, x)
            for axis, reduce_over in ((0, (1, 2)), (1, (1, 3)), (2, (2, 3))):
                along = np.any(seen, axis=reduce_over)  # (n, r): voxel axis x, y or z of each block
                hit = along.any(axis=1)
                if not hit.any():
                    continue
                first = np.argmax(along[hit], axis=1)
                last = r - 1 - np.argmax(along[hit][:, ::-1], axis=1)
                base = keys[hit, axis] * r
                lo[axis] = min(lo[axis], int((base + first).min()))
                hi[axis] = max(hi[axis], int((base + last).max()))
        if lo[0] > hi[0]:
            return np.zeros(3, dtype=np.int64), np.zeros(3, dtype=np.int64)
        return lo, hi

    def _read(self, values: Callable[[np.ndarray, np.ndarray], np.ndarray], fill: float, dtype: type) -> np.ndarray:
        """Dense ``[x, y, z]`` array over :meth:`grid_box` of ``values(tsdf, weight)`` per voxel
        (cells of no allocated block: ``fill``)."""
        r = self.block_resolution
        origin, shape = self.grid_box()
        lo_voxel = np.rint((origin - self.origin) / self.voxel_size).astype(np.int64)
        lo_block = np.floor_divide(lo_voxel, r)
        n_blocks = np.floor_divide(lo_voxel + np.asarray(shape) - 1, r) - lo_block + 1
        out: np.ndarray = np.full(tuple(int(n) * r for n in n_blocks), fill, dtype=dtype)
        nbx, nby, nbz = (int(n) for n in n_blocks)
        by_block = out.reshape(nbx, r, nby, r, nbz, r).transpose(0, 2, 4, 5, 3, 1)  # [bx, by, bz, z, y, x]
        for keys, tsdf, weight in self._chunks():
            rel = keys - lo_block
            inside = np.all((rel >= 0) & (rel < n_blocks), axis=1)
            if inside.any():
                rel = rel[inside]
                by_block[rel[:, 0], rel[:, 1], rel[:, 2]] = values(tsdf[inside], weight[inside])
        start = lo_voxel - lo_block * r
        crop = out[start[0] : start[0] + shape[0], start[1] : start[1] + shape[1], start[2] : start[2] + shape[2]]
        return np.ascontiguousarray(crop)

    def tsdf(self) -> tuple[np.ndarray, np.ndarray]:
        """``(tsdf, weight)`` dense ``float32 [x, y, z]`` grids over :meth:`grid_box` (tsdf
        normalised to [-1, 1]; 0 and weight 0 where never observed)."""
        return (
            self._read(lambda t, w: t, 0.0, np.float32),
            self._read(lambda t, w: w, 0.0, np.float32),
        )

    def labels(self, tsdf: np.ndarray, weight: np.ndarray) -> np.ndarray:
        """Ternary labels ``int8`` of TSDF values and weights (module docstring)."""
        grid = np.full(tsdf.shape, OCCUPIED, dtype=np.int8)
        grid[tsdf * np.float32(self.trunc_voxels) > np.float32(self.empty_margin_voxels)] = EMPTY
        grid[weight <= 0] = UNKNOWN
        return grid

    def ternary(self) -> np.ndarray:
        """The ternary occupancy grid ``int8 [x, y, z]`` over :meth:`grid_box` (-1 unknown, 0 empty,
        1 occupied)."""
        return self._read(self.labels, UNKNOWN, np.int8)

    def mesh(self, weight_threshold: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """The TSDF's zero level set by marching cubes (open3d's, over the allocated blocks):
        ``(vertices float64 (V, 3) in world metres, triangles int64 (F, 3))``.

        Only voxels fused at least ``weight_threshold`` times take part (never-observed cells make no
        surface). With a box, triangles with a vertex outside it (blocks reach past its last cells)
        are dropped.
        """
        if self.allocated_blocks == 0:
            return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
        mesh = self._vbg.extract_triangle_mesh(weight_threshold=float(weight_threshold))
        if "positions" not in mesh.vertex or "indices" not in mesh.triangle:
            return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
        # volume frame: voxel i at i * voxel_size; world = volume + origin + half a voxel
        vertices = mesh.vertex.positions.cpu().numpy().astype(np.float64) + (self.origin + 0.5 * self.voxel_size)
        triangles = mesh.triangle.indices.cpu().numpy().astype(np.int64)
        if self.shape is not None:
            upper = self.origin + np.asarray(self.shape) * self.voxel_size
            outside = np.any((vertices < self.origin - 1e-9) | (vertices > upper + 1e-9), axis=1)
            if outside.any():
                triangles = triangles[~np.any(outside[triangles], axis=1)]
                used = np.unique(triangles)
                renumber = np.full(len(vertices), -1, dtype=np.int64)
                renumber[used] = np.arange(len(used))
                vertices, triangles = vertices[used], renumber[triangles]
        return vertices, triangles

    def save(self, path: str | Path) -> np.ndarray:
        """Write the ternary grid (with origin and resolution) to ``path`` (.npz); return it."""
        origin, _ = self.grid_box()
        grid = self.ternary()
        save_grid(path, grid, origin, self.voxel_size, frames=self.stats.frames)
        return grid


def save_grid(path: str | Path, grid: np.ndarray, origin_m: np.ndarray, voxel_size_m: float, frames: int = 0) -> None:
    """Write a ternary grid to a compressed ``.npz`` (keys ``grid``, ``origin``, ``resolution``, ``frames``)."""
    np.savez_compressed(
        path,
        grid=np.asarray(grid, dtype=np.int8),
        origin=np.asarray(origin_m, dtype=np.float64).reshape(3),
        resolution=np.float64(voxel_size_m),
        frames=np.int64(frames),
    )


def load_grid(path: str | Path) -> tuple[np.ndarray, np.ndarray, float]:
    """Read ``(grid int8, origin (3,), resolution)`` written by :func:`save_grid`.

    Raises:
        ValueError: not a grid file.
    """
    try:
        with np.load(path) as data:
            return data["grid"].astype(np.int8), data["origin"].astype(np.float64), float(data["resolution"])
    except (KeyError, OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a grid .npz file ({exc})") from None
