"""The voxel blocks that one depth frame's TSDF update can touch: a superset, computed per frame.

open3d's ``VoxelBlockGrid.integrate`` updates a voxel (integer point ``x`` of the volume frame,
in voxels) when its optical-frame depth ``z > 0``, it projects to a pixel inside the image
(``0 <= u <= W-1``, ``0 <= v <= H-1``, then truncated) whose depth ``d`` is a valid return
(``0 < d <= depth_max``), and ``z <= d + trunc``: the surface band and all the free space in
front of each return. :func:`frustum_blocks` returns every block (of ``r``³ voxels) holding such
a voxel, plus some that hold none, so fusing only these blocks gives every voxel the value a
fusion over all blocks gives (the dense mode of :class:`~nbv_prob_cnn.perception.TsdfIntegrator`).

Per frame (all conservative, with a pixel and 0.1 mm + 1e-5·z of slack for open3d's float32):
    1. candidate blocks: the bounding box of the frustum from the camera to the farthest return
       + trunc (clipped to the integrator's box, when it has one);
    2. cull blocks whose 8 corners all lie behind the camera, beyond the farthest return + trunc,
       or outside one of the four side planes of the frustum;
    3. project each remaining block's corners to a pixel rectangle (the projection of a box in
       front of the camera lies in the hull of its corners' projections); a block that reaches
       behind the camera plane keeps the whole image;
    4. keep a block when some valid return in its rectangle (a range maximum over 8×8-pixel tiles,
       which can only widen the rectangle) lies no more than ``trunc`` in front of the block's
       nearest corner.
"""

from __future__ import annotations

import numpy as np

__all__ = ["TileRangeMax", "frustum_blocks"]

#: Pixels per edge of the tiles of :class:`TileRangeMax`.
TILE_PX = 8
#: A block whose nearest corner is closer to the camera plane than this [m] keeps the whole image
#: as its rectangle (its corners' projections are not a bound there).
NEAR_PLANE_M = 1e-3
_CORNERS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=np.float64)


class TileRangeMax:
    """Maximum of an image over any pixel rectangle, rounded out to whole tiles (a 2D sparse table
    of the tile maxima: ``O(1)`` per query, four look-ups)."""

    def __init__(self, image: np.ndarray, tile: int = TILE_PX) -> None:
        h, w = image.shape
        th, tw = -(-h // tile), -(-w // tile)
        padded = np.full((th * tile, tw * tile), -np.inf, dtype=np.float32)
        padded[:h, :w] = image
        tiles = padded.reshape(th * tile, tw, tile).max(axis=2).reshape(th, tile, tw).max(axis=1)
        self.tile = tile
        self.levels_y = int(np.floor(np.log2(th))) + 1
        self.levels_x = int(np.floor(np.log2(tw))) + 1
        # table[ky, kx, y, x] = max over tiles [y, y + 2^ky) x [x, x + 2^kx) (-inf where it runs off)
        table = np.full((self.levels_y, self.levels_x, th, tw), -np.inf, dtype=np.float32)
        table[0, 0] = tiles
        for ky in range(self.levels_y):
            if ky > 0:
                s = 1 << (ky - 1)
                table[ky, 0, : th - s] = np.maximum(table[ky - 1, 0, : th - s], table[ky - 1, 0, s:])
            for kx in range(1, self.levels_x):
                s = 1 << (kx - 1)
                table[ky, kx, :, : tw - s] = np.maximum(table[ky, kx - 1, :, : tw - s], table[ky, kx - 1, :, s:])
        self.table = table

    def query(self, u0: np.ndarray, u1: np.ndarray, v0: np.ndarray, v1: np.ndarray) -> np.ndarray:
        """Maximum over the tiles covering each pixel rectangle ``[u0, u1] × [v0, v1]`` (inclusive
        integer pixel indices inside the image)."""
        x0, x1 = u0 // self.tile, u1 // self.tile
        y0, y1 = v0 // self.tile, v1 // self.tile
        kx = np.floor(np.log2(x1 - x0 + 1)).astype(np.int64)
        ky = np.floor(np.log2(y1 - y0 + 1)).astype(np.int64)
        xb, yb = x1 - (1 << kx) + 1, y1 - (1 << ky) + 1
        t = self.table
        return np.maximum(
            np.maximum(t[ky, kx, y0, x0], t[ky, kx, y0, xb]), np.maximum(t[ky, kx, yb, x0], t[ky, kx, yb, xb])
        )


def frustum_blocks(
    depth_m: np.ndarray,
    k_o3d: np.ndarray,
    optical_from_volume: np.ndarray,
    voxel_size: float,
    block_resolution: int,
    trunc_m: float,
    depth_max: float,
    box_blocks: tuple[int, int, int] | None = None,
) -> np.ndarray:
    """``int32 (N, 3)`` coordinates of the blocks a frame's integration can update (module docstring).

    Args:
        depth_m: ``float32 (H, W)`` metres, 0 = no return.
        k_o3d: the 3×3 camera matrix handed to open3d (its principal point, shifted as open3d's
            truncation needs, is the one used here).
        optical_from_volume: 4×4 transform of volume-frame metres (voxel ``x`` at ``x * voxel_size``)
            to the optical frame.
        block_resolution: voxels per block edge.
        trunc_m: TSDF truncation [m].
        depth_max: returns beyond this are not integrated.
        box_blocks: only blocks ``0 <= b < box_blocks`` (the integrator's box), or any.
    """
    h, w = depth_m.shape
    valid = (depth_m > 0) & (depth_m <= depth_max)
    if not valid.any():
        return np.zeros((0, 3), dtype=np.int32)
    returns = np.where(valid, depth_m, -np.inf).astype(np.float32)
    far = float(returns.max()) + trunc_m
    slack = 1e-4 + 1e-5 * far
    fx, fy, cx, cy = float(k_o3d[0, 0]), float(k_o3d[1, 1]), float(k_o3d[0, 2]), float(k_o3d[1, 2])
    r = int(block_resolution)
    # 1. the frustum's bounding box (pixels -1 .. W, -1 .. H: one pixel of slack)
    corners_px = np.array([[u, v] for u in (-1.0, w) for v in (-1.0, h)])
    rays = np.column_stack([(corners_px[:, 0] - cx) / fx, (corners_px[:, 1] - cy) / fy, np.ones(4)])
    apex_and_base = np.vstack([np.zeros(3), rays * (far + slack)])
    volume_from_optical = np.linalg.inv(optical_from_volume)
    in_voxels = (apex_and_base @ volume_from_optical[:3, :3].T + volume_from_optical[:3, 3]) / voxel_size
    lo = np.floor(in_voxels.min(axis=0) / r).astype(np.int64) - 1
    hi = np.floor(in_voxels.max(axis=0) / r).astype(np.int64) + 1
    if box_blocks is not None:
        lo, hi = np.maximum(lo, 0), np.minimum(hi, np.asarray(box_blocks, dtype=np.int64) - 1)
        if np.any(hi < lo):
            return np.zeros((0, 3), dtype=np.int32)
    axes = [np.arange(a, b + 1) for a, b in zip(lo.tolist(), hi.tolist(), strict=True)]
    # optical coordinates of a block's first voxel: a sum of one term per axis (kept separate, so the
    # culling below is three 1D products broadcast over the candidates); the 8 corner offsets
    step = optical_from_volume[:3, :3] * voxel_size
    per_axis = [np.outer(axes[a] * r, step[:, a]) for a in range(3)]  # (n_a, 3) each
    per_axis[0] = per_axis[0] + optical_from_volume[:3, 3]
    offsets = (_CORNERS * (r - 1)) @ step.T  # (8, 3)

    # 2. cull: depth range and the four side half-spaces (a x + b z >= 0), each as min/max over corners
    def extreme(normal: np.ndarray, largest: bool) -> np.ndarray:
        along = offsets @ normal
        x, y, z = (terms @ normal for terms in per_axis)
        return x[:, None, None] + y[None, :, None] + (z + (along.max() if largest else along.min()))[None, None, :]

    planes = np.array([[fx, 0.0, cx + 1.0], [-fx, 0.0, w - cx], [0.0, fy, cy + 1.0], [0.0, -fy, h - cy]])
    z_axis = np.array([0.0, 0.0, 1.0])
    keep = (extreme(z_axis, True) > 0) & (extreme(z_axis, False) <= far + slack)
    for plane in planes:
        keep &= extreme(plane, True) >= -slack * np.linalg.norm(plane)
    ix, iy, iz = np.nonzero(keep)
    if len(ix) == 0:
        return np.zeros((0, 3), dtype=np.int32)
    blocks = np.column_stack([axes[0][ix], axes[1][iy], axes[2][iz]])
    first = per_axis[0][ix] + per_axis[1][iy] + per_axis[2][iz]
    z_near = first[:, 2] + offsets[:, 2].min()
    # 3. pixel rectangles from the corners (blocks reaching the camera plane: the whole image)
    u_lo, v_lo = np.zeros(len(blocks)), np.zeros(len(blocks))
    u_hi, v_hi = np.full(len(blocks), w - 1.0), np.full(len(blocks), h - 1.0)
    ahead = z_near >= NEAR_PLANE_M
    pts = first[ahead]
    ul = vl = np.full(len(pts), np.inf)
    uh = vh = np.full(len(pts), -np.inf)
    for offset in offsets:
        z = pts[:, 2] + offset[2]
        u = fx * (pts[:, 0] + offset[0]) / z
        v = fy * (pts[:, 1] + offset[1]) / z
        ul, uh, vl, vh = np.minimum(ul, u), np.maximum(uh, u), np.minimum(vl, v), np.maximum(vh, v)
    u_lo[ahead], u_hi[ahead], v_lo[ahead], v_hi[ahead] = ul + cx, uh + cx, vl + cy, vh + cy
    inside = (u_hi >= -1.0) & (u_lo <= w) & (v_hi >= -1.0) & (v_lo <= h)
    blocks, z_near = blocks[inside], z_near[inside]
    iu0 = np.clip(np.floor(u_lo[inside]) - 1, 0, w - 1).astype(np.int64)
    iu1 = np.clip(np.floor(u_hi[inside]) + 1, 0, w - 1).astype(np.int64)
    iv0 = np.clip(np.floor(v_lo[inside]) - 1, 0, h - 1).astype(np.int64)
    iv1 = np.clip(np.floor(v_hi[inside]) + 1, 0, h - 1).astype(np.int64)
    # 4. some return in the rectangle no more than trunc in front of the block's nearest voxel
    deepest = TileRangeMax(returns).query(iu0, iu1, iv0, iv1)
    needed = deepest.astype(np.float64) + trunc_m + slack >= z_near
    return blocks[needed].astype(np.int32)
