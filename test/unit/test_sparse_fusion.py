"""Fusion that follows the view (issue 34, item 3): the blocks a frame can touch, chosen per frame, give
the cells of a fusion over every block of the box; an open grid grows as the scene is seen."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

pytest.importorskip("open3d")
trimesh = pytest.importorskip("trimesh")

from nbv_prob_cnn.basics.camera import look_rotation  # noqa: E402
from nbv_prob_cnn.basics.grid import UNKNOWN  # noqa: E402
from nbv_prob_cnn.perception import DepthCamera, Intrinsics, TsdfIntegrator  # noqa: E402
from nbv_prob_cnn.perception import tsdf as tsdf_module  # noqa: E402
from nbv_prob_cnn.perception.depth_camera import room_mesh  # noqa: E402
from nbv_prob_cnn.perception.frustum_blocks import TileRangeMax, frustum_blocks  # noqa: E402
from nbv_prob_cnn.sensing.sensor_noise import sensor_noise  # noqa: E402


def look_at(position, target) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = look_rotation(np.asarray(target, float) - np.asarray(position, float))
    pose[:3, 3] = position
    return pose


# ------------------------------------------------------------------------- range maximum
def test_tile_range_max_is_the_maximum_over_the_covering_tiles():
    rng = np.random.default_rng(0)
    image = rng.uniform(0.5, 4.0, (37, 53)).astype(np.float32)
    image[rng.random(image.shape) < 0.3] = -np.inf
    table = TileRangeMax(image, tile=4)
    u0 = rng.integers(0, 53, 500)
    u1 = np.minimum(u0 + rng.integers(0, 53, 500), 52)
    v0 = rng.integers(0, 37, 500)
    v1 = np.minimum(v0 + rng.integers(0, 37, 500), 36)
    got = table.query(u0, u1, v0, v1)
    for i in range(500):  # slow reference: the tiles covering the rectangle, pixel by pixel
        ref = image[(v0[i] // 4) * 4 : (v1[i] // 4 + 1) * 4, (u0[i] // 4) * 4 : (u1[i] // 4 + 1) * 4].max()
        assert got[i] == ref


# ------------------------------------------------------------- blocks: a superset, by hand
def updated_blocks_reference(depth, k, optical_from_volume, voxel, r, trunc, depth_max, box_voxels):
    """The blocks holding a voxel open3d's integration updates, voxel by voxel (float64):
    z > 0, inside the image, a valid return d at the truncated pixel, z <= d + trunc."""
    h, w = depth.shape
    grid = np.stack(np.meshgrid(*[np.arange(n) for n in box_voxels], indexing="ij"), axis=-1).reshape(-1, 3)
    cam = (grid * voxel) @ optical_from_volume[:3, :3].T + optical_from_volume[:3, 3]
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = k[0, 0] * cam[:, 0] / z + k[0, 2]
        v = k[1, 1] * cam[:, 1] / z + k[1, 2]
    inside = (z > 0) & (u >= 0) & (v >= 0) & (u <= w - 1) & (v <= h - 1)
    d = np.zeros(len(grid))
    d[inside] = depth[v[inside].astype(int), u[inside].astype(int)]
    updated = inside & (d > 0) & (d <= depth_max) & (z <= d + trunc)
    return {tuple(b) for b in np.unique(grid[updated] // r, axis=0)}


@pytest.mark.parametrize(
    ("position", "target"),
    [
        ((-0.4, 0.3, 0.5), (0.5, 0.5, 0.3)),  # outside the box, looking in
        ((0.30, 0.32, 0.31), (0.9, 0.1, 0.2)),  # inside the box
        ((0.32, 0.32, 0.32), (0.32, 0.32, -1.0)),  # on a block corner, looking straight down
        ((0.5, 0.5, 0.5), (0.5, 1.5, 0.5)),  # inside, along an axis
        ((1.2, -0.3, 0.9), (0.2, 0.6, 0.0)),
    ],
)
def test_frustum_blocks_hold_every_voxel_a_frame_updates(position, target):
    rng = np.random.default_rng(int(1000 * position[0]) % 97)
    intrinsics = Intrinsics(40, 30, 30.0, 31.0, 19.7, 14.2)
    depth = rng.uniform(0.05, 1.6, intrinsics.shape).astype(np.float32)
    depth[rng.random(intrinsics.shape) < 0.2] = 0.0
    depth[rng.random(intrinsics.shape) < 0.05] = 3.0  # beyond depth_max: no return
    voxel, r, box_voxels = 0.02, 8, (48, 48, 40)
    k = intrinsics.matrix
    k[:2, 2] += 0.5  # as the integrator hands it to open3d
    optical_from_volume = np.linalg.inv(look_at(position, target))
    trunc, depth_max = 3 * voxel, 2.0
    box_blocks = tuple(-(-n // r) for n in box_voxels)
    chosen = frustum_blocks(depth, k, optical_from_volume, voxel, r, trunc, depth_max, box_blocks)
    chosen_set = {tuple(b) for b in chosen}
    assert len(chosen_set) == len(chosen)  # no block twice
    needed = updated_blocks_reference(depth, k, optical_from_volume, voxel, r, trunc, depth_max, box_voxels)
    assert needed, "the case must update something"
    assert needed <= chosen_set
    assert len(chosen_set) < math.prod(box_blocks)  # and it leaves blocks out
    assert np.all((chosen >= 0) & (chosen < box_blocks))


def test_no_return_no_blocks():
    intrinsics = Intrinsics(40, 30, 30.0, 30.0, 20.0, 15.0)
    empty = np.zeros(intrinsics.shape, np.float32)
    assert len(frustum_blocks(empty, intrinsics.matrix, np.eye(4), 0.02, 8, 0.06, 2.0)) == 0
    far = np.full(intrinsics.shape, 5.0, np.float32)
    assert len(frustum_blocks(far, intrinsics.matrix, np.eye(4), 0.02, 8, 0.06, 2.0)) == 0


# -------------------------------------------------- sparse against dense on simulated scenes
BOXES = [
    (np.array([0.10, 0.10, 0.00]), np.array([1.38, 1.38, 0.20])),
    (np.array([0.50, 0.55, 0.20]), np.array([0.70, 0.75, 0.45])),
]
VOXEL, SHAPE, ORIGIN = 0.0116, (128, 128, 96), np.zeros(3)


@pytest.fixture(scope="module")
def frames():
    """Frames of a tabletop in the 3DT box, inside a room a little larger than the box (returns
    beyond the box, as in a lab): around the table, from inside the box close to the table, and a
    noisy sensor (holes, grazing dropouts)."""
    meshes = [trimesh.creation.box(bounds=np.stack(b)) for b in BOXES]
    meshes.append(room_mesh(np.array([-0.6, -0.5, -0.3]), np.array([2.1, 2.0, 1.9])))
    intrinsics = Intrinsics.from_hfov(160, 120, 60.0)
    exact = DepthCamera(meshes, intrinsics)
    noisy = DepthCamera(meshes, intrinsics, noise=sensor_noise("kinect_v1"), noise_seed=3)
    target = np.array([0.7, 0.7, 0.3])
    out = []
    for i, azimuth in enumerate(range(0, 360, 45)):
        a = math.radians(azimuth)
        pose = look_at(target + [0.9 * math.cos(a), 0.9 * math.sin(a), 0.5 + 0.1 * (i % 2)], target)
        out.append(((noisy if i % 2 else exact).render(pose), pose))
    for position, look in (((0.62, 0.66, 0.52), (0.6, 0.65, 0.3)), ((0.2, 0.2, 0.9), (1.3, 1.3, 0.1))):
        pose = look_at(position, look)
        out.append((exact.render(pose), pose))
    return intrinsics, out


def fused(frames, **kwargs) -> TsdfIntegrator:
    intrinsics, posed = frames
    integrator = TsdfIntegrator(**{"origin_m": ORIGIN, "shape_cells": SHAPE, "voxel_size_m": VOXEL, **kwargs})
    for depth, pose in posed:
        integrator.integrate(depth, intrinsics, pose, depth_max=3.0)
    return integrator


def test_sparse_gives_the_dense_cells_exactly(frames):
    dense, sparse = fused(frames, fusion="dense"), fused(frames, fusion="sparse")
    assert sparse.fusion == "sparse" and dense.fusion == "dense"
    for a, b in zip(dense.tsdf(), sparse.tsdf(), strict=True):
        np.testing.assert_array_equal(a, b)  # tsdf and weight, bit for bit
    grid = sparse.ternary()
    np.testing.assert_array_equal(dense.ternary(), grid)
    counts = [int(np.count_nonzero(grid == v)) for v in (-1, 0, 1)]
    assert min(counts) > 1000  # every label present
    # sparse allocated fewer blocks than the box has
    assert sparse.allocated_blocks < math.prod(-(-s // sparse.block_resolution) for s in SHAPE)


def test_sparse_block_sizes_and_growth_give_the_same_cells(frames, monkeypatch):
    reference = fused(frames, fusion="dense").ternary()
    np.testing.assert_array_equal(fused(frames, fusion="sparse", block_resolution=16).ternary(), reference)
    # a hash map that starts tiny grows many times (every growth zeroes the new free slots)
    monkeypatch.setattr(tsdf_module, "INITIAL_BLOCKS", 4)
    small = fused(frames, fusion="sparse")
    assert small._vbg.hashmap().capacity() >= small.allocated_blocks > 4
    np.testing.assert_array_equal(small.ternary(), reference)


def test_open_grid_grows_as_seen_and_matches_a_box_around_it(frames):
    # the same lattice anchor for both, so open3d computes every voxel in the same (float32) frame
    anchor = np.array([-1.0, -1.0, -0.5])
    open_grid = fused(frames, origin_m=anchor, shape_cells=None)
    origin, shape = open_grid.grid_box()
    grid = open_grid.ternary()
    assert grid.shape == shape
    # a box that holds everything seen: the open grid is its observed part, cell for cell
    big = fused(frames, origin_m=anchor, shape_cells=(300, 300, 240))
    offset = np.rint((origin - anchor) / VOXEL).astype(int)
    np.testing.assert_allclose(origin - anchor, offset * VOXEL, atol=1e-12)
    window = tuple(slice(o, o + n) for o, n in zip(offset, shape, strict=True))
    full = big.ternary()
    np.testing.assert_array_equal(full[window], grid)
    outside = full.copy()
    outside[window] = UNKNOWN
    assert np.all(outside == UNKNOWN)
    # the observed box is tight: every face of it holds an observed cell
    for axis in range(3):
        seen = np.moveaxis(grid != UNKNOWN, axis, 0)
        assert seen[0].any() and seen[-1].any()
    # the returns reach the room's walls beyond the 3DT box
    assert origin[0] < 0 and origin[0] + shape[0] * VOXEL > 1.48


def test_open_grid_needs_sparse_fusion_and_starts_empty():
    with pytest.raises(ValueError, match="dense fusion needs a box"):
        TsdfIntegrator(shape_cells=None, fusion="dense")
    with pytest.raises(ValueError, match="fusion: expected one of"):
        TsdfIntegrator(fusion="octree")
    empty = TsdfIntegrator(origin_m=(0.1, 0.2, 0.3), shape_cells=None, voxel_size_m=0.05)
    origin, shape = empty.grid_box()
    assert shape == (1, 1, 1) and np.allclose(origin, (0.1, 0.2, 0.3))
    assert empty.ternary().tolist() == [[[UNKNOWN]]]


def test_reset_frees_the_blocks(frames):
    integrator = fused(frames)
    assert integrator.allocated_blocks > 0 and integrator.stats.blocks_updated > 0
    integrator.reset()
    assert integrator.allocated_blocks == 0 and integrator.stats.frames == 0
    assert np.all(integrator.ternary() == UNKNOWN)


# ------------------------------------------------------------------------------ nbv integrate
FUSED_LINE = re.compile(
    r"^fused (\d+) frames in ([\d.]+) s \(([\d.]+) frames/s\), grid (\d+) x (\d+) x (\d+) at ([\d.]+) m, "
    r"peak RSS (\d+) MB$"
)


def test_integrate_bounds_auto_ends_with_the_fusion_line(frames, tmp_path, capsys):
    from nbv_prob_cnn.cli import main
    from nbv_prob_cnn.perception import BagWriter, load_grid

    intrinsics, posed = frames
    bag = tmp_path / "bag"
    with BagWriter(bag) as writer:
        for i, (depth, pose) in enumerate(posed):
            writer.write_frame(1_000_000_000 + i * 100_000_000, depth, intrinsics, pose)
    out = tmp_path / "grid.npz"
    args = ["integrate", "--bag", str(bag), "--voxel", str(VOXEL), "--bounds", "auto", "--out", str(out)]
    assert main(args) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    match = FUSED_LINE.match(last)
    assert match, last
    n, seconds, rate = int(match[1]), float(match[2]), float(match[3])
    assert n == len(posed) and rate == pytest.approx(n / seconds, rel=0.05)
    grid, origin, resolution = load_grid(out)
    assert tuple(int(match[i]) for i in (4, 5, 6)) == grid.shape and resolution == VOXEL
    assert 0 < int(match[8]) < 4000
    # the grid is the open grid fused in this process (the bag holds 32FC1 metres)
    expected = TsdfIntegrator((0.0, 0.0, 0.0), None, VOXEL)
    for depth, pose in posed:
        expected.integrate(depth, intrinsics, pose)
    np.testing.assert_allclose(origin, expected.grid_box()[0], atol=1e-9)
    np.testing.assert_array_equal(grid, expected.ternary())
    assert main([*args[:-2], "--fusion", "dense", "--out", str(tmp_path / "x.npz")]) == 2
    assert "--bounds auto needs --fusion sparse" in capsys.readouterr().err


def test_integrate_sample_bag_sparse_and_dense_write_the_same_grid(tmp_path, capsys):
    from pathlib import Path

    from nbv_prob_cnn.cli import main
    from nbv_prob_cnn.perception import load_grid

    sample = Path(__file__).resolve().parents[2] / "bags" / "3dt_seed1000_sample"
    grids = []
    for mode in ("sparse", "dense"):
        out = tmp_path / f"{mode}.npz"
        assert main(["integrate", "--bag", str(sample), "--fusion", mode, "--out", str(out)]) == 0
        assert FUSED_LINE.match(capsys.readouterr().out.strip().splitlines()[-1])
        grids.append(load_grid(out))
    np.testing.assert_array_equal(grids[0][0], grids[1][0])
    assert grids[0][0].shape == SHAPE and np.all(grids[0][1] == 0.0)


def test_fusion_suite_puts_dense_and_sparse_side_by_side(tmp_path):
    from PIL import Image

    from nbv_prob_cnn.bench.fusion import fusion_suite

    # a 7-Scenes folder: three 640x480 frames of a wall 1.5 m ahead, the camera stepping sideways
    folder = tmp_path / "seq"
    folder.mkdir()
    for i in range(3):
        Image.fromarray(np.full((480, 640), 1500, np.uint16)).save(folder / f"frame-{i:06d}.depth.png")
        pose = np.eye(4)
        pose[0, 3] = 0.1 * i
        np.savetxt(folder / f"frame-{i:06d}.pose.txt", pose)
    table = fusion_suite(recording=folder, voxels=(0.1,), frames=3, three_dt_frames=0)
    rows = [line for line in table.splitlines() if line.startswith("| seq |")]
    assert [row.split("|")[3].strip() for row in rows] == ["dense", "sparse", "sparse"]
    assert rows[1].split("|")[-2].strip() == "0"  # sparse over the box: no cell differs from dense
    assert rows[2].split("|")[-2].strip() == "0 (its window of the box)"
    assert "| 3 |" in rows[0]
    absent = fusion_suite(recording=tmp_path / "absent", three_dt_frames=0)
    assert f"recording cases skipped: the shared recording is absent ({tmp_path / 'absent'})" in absent
