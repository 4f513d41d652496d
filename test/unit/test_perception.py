"""Tests of nbv_prob_cnn.perception: simulated depth camera, TSDF ternary grids, rosbag2 I/O."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("open3d")
trimesh = pytest.importorskip("trimesh")
pytest.importorskip("rosbags")

from nbv_prob_cnn import cli  # noqa: E402
from nbv_prob_cnn.basics.camera import look_rotation  # noqa: E402
from nbv_prob_cnn.basics.grid import EMPTY, OCCUPIED, UNKNOWN  # noqa: E402
from nbv_prob_cnn.perception import (  # noqa: E402
    BagError,
    BagWriter,
    DepthCamera,
    DepthNoise,
    Intrinsics,
    TsdfIntegrator,
    load_grid,
    read_frames,
)
from nbv_prob_cnn.perception.bags import (  # noqa: E402
    TOPIC_CAMERA_INFO,
    TOPIC_IMAGE,
    TOPIC_POSE,
    BagWarning,
    depth_to_image_msg,
    image_msg_to_depth,
    intrinsics_to_camera_info,
    pose_to_transform_msg,
    typestore,
)

VOXEL = 0.0116
SHAPE = (128, 128, 96)
ORIGIN = np.zeros(3)

# primitive scene inside the 3DT box (metres): a table slab, a box on it, a sphere on it
BOXES = [
    (np.array([0.10, 0.10, 0.00]), np.array([1.38, 1.38, 0.20])),
    (np.array([0.50, 0.55, 0.20]), np.array([0.70, 0.75, 0.45])),
]
SPHERE = (np.array([0.95, 0.80, 0.33]), 0.13)
TARGET = np.array([0.75, 0.70, 0.30])


def look_at(position: np.ndarray, target: np.ndarray) -> np.ndarray:
    """world_from_optical pose at ``position`` looking at ``target``."""
    pose = np.eye(4)
    pose[:3, :3] = look_rotation(np.asarray(target, float) - np.asarray(position, float))
    pose[:3, 3] = position
    return pose


def scene_meshes() -> list:
    meshes = [trimesh.creation.box(bounds=np.stack(b)) for b in BOXES]
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=SPHERE[1])
    sphere.apply_translation(SPHERE[0])
    return meshes + [sphere]


def scene_ground_truth() -> np.ndarray:
    """Analytic voxelization: a cell is occupied when its cube overlaps a primitive (the sphere
    is tested against the exact sphere, not its polygon approximation)."""
    lo = [ORIGIN[a] + np.arange(SHAPE[a]) * VOXEL for a in range(3)]
    hi = [c + VOXEL for c in lo]
    truth = np.zeros(SHAPE, dtype=bool)
    for b_lo, b_hi in BOXES:
        m = [(hi[a] > b_lo[a]) & (lo[a] < b_hi[a]) for a in range(3)]
        truth |= m[0][:, None, None] & m[1][None, :, None] & m[2][None, None, :]
    centre, radius = SPHERE
    gap = [np.maximum(0.0, np.maximum(lo[a] - centre[a], centre[a] - hi[a])) for a in range(3)]
    dist2 = gap[0][:, None, None] ** 2 + gap[1][None, :, None] ** 2 + gap[2][None, None, :] ** 2
    return truth | (dist2 <= radius**2)


def quality_poses() -> list[np.ndarray]:
    poses = []
    for azimuth in (0.0, 100.0, 200.0, 290.0):
        a = np.radians(azimuth)
        poses.append(look_at(TARGET + np.array([0.6 * np.cos(a), 0.6 * np.sin(a), 0.45]), TARGET))
    return poses


@pytest.fixture(scope="module")
def scene() -> dict:
    """Rendered frames of the primitive scene, their TSDF grid, and the seen surface cells."""
    intrinsics = Intrinsics.from_hfov()
    camera = DepthCamera(scene_meshes(), intrinsics)
    poses = quality_poses()
    depths = [camera.render(p) for p in poses]
    integrator = TsdfIntegrator(ORIGIN, SHAPE, VOXEL)
    seen = np.zeros(SHAPE, dtype=bool)
    for depth, pose in zip(depths, poses, strict=True):
        integrator.integrate(depth, intrinsics, pose)
        points = intrinsics.backproject(depth) @ pose[:3, :3].T + pose[:3, 3]
        ijk = np.floor((points - ORIGIN) / VOXEL).astype(int)
        ijk = ijk[np.all((ijk >= 0) & (ijk < SHAPE), axis=1)]
        seen[tuple(ijk.T)] = True
    return {
        "intrinsics": intrinsics,
        "camera": camera,
        "poses": poses,
        "depths": depths,
        "grid": integrator.ternary(),
        "truth": scene_ground_truth(),
        "seen": seen,
    }


# ------------------------------------------------------------------------------ camera
def test_intrinsics_from_hfov() -> None:
    intr = Intrinsics.from_hfov()
    assert (intr.width, intr.height) == (640, 480)
    assert intr.fx == pytest.approx(320.0 / np.tan(np.radians(30.0)))
    assert intr.fy == intr.fx and intr.cx == 319.5 and intr.cy == 239.5
    with pytest.raises(ValueError):
        Intrinsics.from_hfov(hfov_deg=180.0)
    with pytest.raises(ValueError):
        Intrinsics(0, 10, 1.0, 1.0, 0.0, 0.0)


def test_render_box_depth_is_analytic_z_depth() -> None:
    box = trimesh.creation.box(bounds=np.array([[0.2, 0.2, 0.1], [0.8, 0.8, 0.3]]))
    intr = Intrinsics.from_hfov(160, 120, 60.0)
    camera = DepthCamera([box], intr)
    # looking straight down from 0.9 m: the box top (z = 0.3) is at z-depth 0.6 in every pixel it fills
    down = look_at(np.array([0.5, 0.5, 0.9]), np.array([0.5, 0.5, 0.0]))
    depth = camera.render(down)
    assert depth.dtype == np.float32 and depth.shape == (120, 160)
    rays = intr.pixel_rays() @ down[:3, :3].T  # world directions with unit optical z
    hit = down[:3, 3] + rays * 0.6
    on_top = np.all((hit[..., :2] > 0.2 + 1e-4) & (hit[..., :2] < 0.8 - 1e-4), axis=-1)
    assert on_top.sum() > 1000
    np.testing.assert_allclose(depth[on_top], 0.6, atol=1e-5)
    # z-depth, not ray length: the corner pixels are as deep as the centre
    # tilted view of a wall: x = 0.2 face seen from x = -0.5 along +x, off-centre
    side = look_at(np.array([-0.5, 0.45, 0.2]), np.array([0.5, 0.55, 0.2]))
    depth = camera.render(side)
    rays = intr.pixel_rays() @ side[:3, :3].T
    t = (0.2 - side[0, 3]) / rays[..., 0]  # ray parameter = z-depth (unit optical z)
    hit = side[:3, 3] + rays * t[..., None]
    on_face = (np.abs(hit[..., 1] - 0.5) < 0.3 - 1e-4) & (np.abs(hit[..., 2] - 0.2) < 0.1 - 1e-4)
    assert on_face.sum() > 500
    np.testing.assert_allclose(depth[on_face], t[on_face], rtol=1e-5)
    # rays that miss everything are "no return"
    up = look_at(np.array([0.5, 0.5, 0.9]), np.array([0.5, 0.5, 2.0]))
    assert not camera.render(up).any()


def test_noise_off_by_default_and_seeded() -> None:
    meshes = scene_meshes()
    intr = Intrinsics.from_hfov(160, 120)
    pose = quality_poses()[0]
    exact = DepthCamera(meshes, intr).render(pose)
    assert np.array_equal(DepthCamera(meshes, intr).render(pose), exact)
    noisy = [DepthCamera(meshes, intr, DepthNoise(0.01, 0.1, seed=7)).render(pose) for _ in range(2)]
    assert np.array_equal(noisy[0], noisy[1])
    other = DepthCamera(meshes, intr, DepthNoise(0.01, 0.1, seed=8)).render(pose)
    assert not np.array_equal(other, noisy[0])
    valid = exact > 0
    dropped = valid & (noisy[0] == 0)
    assert 0.05 < dropped.sum() / valid.sum() < 0.15
    kept = valid & (noisy[0] > 0)
    rel = (noisy[0][kept] - exact[kept]) / exact[kept]
    assert 0.007 < rel.std() < 0.013 and abs(rel.mean()) < 0.002
    assert not noisy[0][~valid].any()


# ------------------------------------------------------------------------------ TSDF
def test_tsdf_quality_on_primitive_scene(scene: dict) -> None:
    grid, truth, seen = scene["grid"], scene["truth"], scene["seen"]
    assert grid.dtype == np.int8 and grid.shape == SHAPE
    empty, occupied = grid == EMPTY, grid == OCCUPIED
    empty_precision = 1.0 - truth[empty].mean()
    surface = seen & truth
    recall = occupied[surface].mean()
    print(
        f"\nTSDF quality: observed {np.mean(grid != UNKNOWN):.3f}, empty precision {empty_precision:.4f} "
        f"({empty.sum()} empty cells), surface recall {recall:.4f} ({surface.sum()} seen surface cells), "
        f"occupied precision {truth[occupied].mean():.3f}"
    )
    assert empty.sum() > 100_000 and surface.sum() > 5_000
    assert empty_precision >= 0.95
    assert recall >= 0.90


def test_tsdf_quality_with_sensor_noise(scene: dict) -> None:
    """Same thresholds with 2 mm/m depth noise and 2 % dropouts (seeded)."""
    intrinsics, truth, seen = scene["intrinsics"], scene["truth"], scene["seen"]
    camera = DepthCamera(scene_meshes(), intrinsics, DepthNoise(sigma_per_m=0.002, dropout=0.02, seed=1))
    integrator = TsdfIntegrator(ORIGIN, SHAPE, VOXEL)
    for pose in scene["poses"]:
        integrator.integrate(camera.render(pose), intrinsics, pose)
    grid = integrator.ternary()
    empty_precision = 1.0 - truth[grid == EMPTY].mean()
    recall = (grid == OCCUPIED)[seen & truth].mean()
    print(f"\nTSDF quality with noise: empty precision {empty_precision:.4f}, surface recall {recall:.4f}")
    assert empty_precision >= 0.95
    assert recall >= 0.90


def test_unobserved_cells_stay_unknown(scene: dict) -> None:
    grid, truth = scene["grid"], scene["truth"]
    fresh = TsdfIntegrator(ORIGIN, SHAPE, VOXEL)
    assert (fresh.ternary() == UNKNOWN).all()
    # inside the table slab, deeper than the truncation below its top face (z = 0.2 m)
    deep = grid[20:100, 20:100, : int(0.2 / VOXEL) - 5]
    assert (deep == UNKNOWN).all()
    # cells no camera ray reaches are unknown; every known cell lies in front of or just behind a surface
    assert (grid == UNKNOWN).sum() > 0.5 * grid.size
    assert truth[grid == UNKNOWN].sum() > 0
    # a single top-down view over one corner leaves the opposite corner unknown
    one = TsdfIntegrator(ORIGIN, SHAPE, VOXEL)
    pose = look_at(np.array([0.3, 0.3, 0.6]), np.array([0.3, 0.3, 0.0]))
    one.integrate(scene["camera"].render(pose), scene["intrinsics"], pose)
    partial = one.ternary()
    assert (partial[90:, 90:, :] == UNKNOWN).all()
    assert (partial[20:30, 20:30, 20:30] == EMPTY).all()


def test_nan_and_zero_are_no_return(scene: dict) -> None:
    intr, depth, pose = scene["intrinsics"], scene["depths"][0], scene["poses"][0]
    grids = []
    for fill in (np.nan, 0.0, -1.0, np.inf):
        d = depth.copy()
        d[:, :320] = fill
        tsdf = TsdfIntegrator(ORIGIN, SHAPE, VOXEL)
        tsdf.integrate(d, intr, pose)
        grids.append(tsdf.ternary())
    for g in grids[1:]:
        assert np.array_equal(g, grids[0])
    full = TsdfIntegrator(ORIGIN, SHAPE, VOXEL)
    full.integrate(depth, intr, pose)
    full_grid = full.ternary()
    assert (grids[0] != UNKNOWN).sum() < 0.7 * (full_grid != UNKNOWN).sum()
    all_nan = TsdfIntegrator(ORIGIN, SHAPE, VOXEL)
    all_nan.integrate(np.full_like(depth, np.nan), intr, pose)
    assert (all_nan.ternary() == UNKNOWN).all()


def test_16uc1_and_32fc1_give_the_same_grid(scene: dict) -> None:
    intr = scene["intrinsics"]
    mm = [np.round(d * 1000.0).astype(np.uint16) for d in scene["depths"][:2]]
    as_int, as_float = TsdfIntegrator(ORIGIN, SHAPE, VOXEL), TsdfIntegrator(ORIGIN, SHAPE, VOXEL)
    for depth_mm, pose in zip(mm, scene["poses"][:2], strict=True):
        as_int.integrate(depth_mm, intr, pose)
        as_float.integrate(depth_mm.astype(np.float32) / np.float32(1000.0), intr, pose)
    assert np.array_equal(as_int.ternary(), as_float.ternary())


def test_reset_save_and_load(scene: dict, tmp_path: Path) -> None:
    tsdf = TsdfIntegrator(ORIGIN, SHAPE, VOXEL)
    tsdf.integrate(scene["depths"][0], scene["intrinsics"], scene["poses"][0])
    grid = tsdf.save(tmp_path / "grid.npz")
    loaded, origin, resolution = load_grid(tmp_path / "grid.npz")
    assert np.array_equal(loaded, grid) and np.array_equal(origin, ORIGIN) and resolution == VOXEL
    tsdf.reset()
    assert (tsdf.ternary() == UNKNOWN).all() and tsdf.stats.frames == 0


def test_refine_pose_icp_reduces_a_pose_error(scene: dict) -> None:
    intr, camera = scene["intrinsics"], scene["camera"]
    tsdf = TsdfIntegrator(ORIGIN, SHAPE, VOXEL, refine_pose_icp=True)
    first = look_at(TARGET + np.array([0.6, 0.0, 0.45]), TARGET)
    tsdf.integrate(camera.render(first), intr, first)
    second = look_at(TARGET + np.array([0.58, 0.15, 0.45]), TARGET)
    error = np.eye(4)
    error[:3, 3] = [0.012, -0.008, 0.006]
    used = tsdf.integrate(camera.render(second), intr, second @ error)
    residual = np.linalg.norm((np.linalg.inv(second) @ used)[:3, 3])
    assert residual < 0.5 * np.linalg.norm(error[:3, 3])


# ------------------------------------------------------------------------------ bags
def _write_bag(path: Path, frames: list[tuple[int, np.ndarray, Intrinsics, np.ndarray]], encoding: str) -> None:
    with BagWriter(path) as bag:
        for stamp, depth, intr, pose in frames:
            bag.write_frame(stamp, depth, intr, pose, encoding=encoding)


def _random_frames(n: int = 4) -> list[tuple[int, np.ndarray, Intrinsics, np.ndarray]]:
    rng = np.random.default_rng(3)
    intr = Intrinsics(64, 48, 50.5, 51.25, 31.75, 23.25)
    frames = []
    for i in range(n):
        depth = (rng.random((48, 64)) * 2.0).astype(np.float32)
        depth[0, :5] = np.nan
        depth[1, :5] = 0.0
        pose = look_at(rng.random(3), rng.random(3) + 1.0)
        frames.append((1_700_000_000_123_456_789 + i * 33_333_333, depth, intr, pose))
    return frames


def test_bag_round_trip_is_exact(tmp_path: Path) -> None:
    frames = _random_frames()
    _write_bag(tmp_path / "bag32", frames, "32FC1")
    _write_bag(tmp_path / "bag16", frames, "16UC1")
    read32 = list(read_frames(tmp_path / "bag32"))
    read16 = list(read_frames(next((tmp_path / "bag16").glob("*.mcap"))))  # a bare .mcap file works too
    assert len(read32) == len(read16) == len(frames)
    for (stamp, depth, intr, pose), f32, f16 in zip(frames, read32, read16, strict=True):
        assert f32.stamp_ns == stamp and f16.stamp_ns == stamp
        assert f32.depth_m.dtype == np.float32 and np.array_equal(f32.depth_m, depth, equal_nan=True)
        assert f32.intrinsics == intr and f16.intrinsics == intr
        np.testing.assert_allclose(f32.pose_4x4, pose, atol=1e-12)
        mm = np.nan_to_num(np.round(depth.astype(np.float64) * 1000.0)).astype(np.uint16)
        assert np.array_equal(f16.depth_m, mm.astype(np.float32) / np.float32(1000.0))


def test_image_conversion_handles_padding_and_endianness() -> None:
    depth = np.arange(12, dtype=np.float32).reshape(3, 4) / 10.0
    msg = depth_to_image_msg(depth, 5, "32FC1")
    padded = np.zeros((3, 4 * 4 + 8), dtype=np.uint8)
    padded[:, :16] = np.frombuffer(depth.astype(">f4").tobytes(), dtype=np.uint8).reshape(3, 16)
    msg.data, msg.step, msg.is_bigendian = padded.reshape(-1), 24, 1
    assert np.array_equal(image_msg_to_depth(msg), depth)
    mm = depth_to_image_msg(np.array([[0.0, 0.0015, np.nan, 70.0]], np.float32), 5, "16UC1")
    np.testing.assert_array_equal(image_msg_to_depth(mm), np.array([[0.0, 0.002, 0.0, 0.0]], np.float32))
    msg.step = 8
    with pytest.raises(ValueError, match="step"):
        image_msg_to_depth(msg)


def test_wrong_encoding_is_rejected(tmp_path: Path) -> None:
    depth = np.ones((4, 4), np.float32)
    with pytest.raises(ValueError, match="mono8"):
        depth_to_image_msg(depth, 0, "mono8")
    msg = depth_to_image_msg(depth, 0)
    msg.encoding = "rgb8"
    with pytest.raises(ValueError, match="rgb8"):
        image_msg_to_depth(msg)
    # a bag recorded with another encoding
    from rosbags.rosbag2 import StoragePlugin, Writer

    store, intr = typestore(), Intrinsics.from_hfov(4, 4)
    msg.encoding = "8UC1"
    with Writer(tmp_path / "bad", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        items = (
            (TOPIC_IMAGE, msg),
            (TOPIC_CAMERA_INFO, intrinsics_to_camera_info(intr, 0)),
            (TOPIC_POSE, pose_to_transform_msg(np.eye(4), 0)),
        )
        for topic, m in items:
            conn = writer.add_connection(topic, m.__msgtype__, typestore=store)
            writer.write(conn, 0, store.serialize_cdr(m, m.__msgtype__))
    with pytest.raises(ValueError, match="8UC1"):
        read_frames(tmp_path / "bad")


def test_unpaired_messages_warn_or_fail_when_strict(tmp_path: Path) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer

    store, intr = typestore(), Intrinsics.from_hfov(4, 4)
    with Writer(tmp_path / "bag", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}
        for topic, stamps in ((TOPIC_IMAGE, (1, 2)), (TOPIC_CAMERA_INFO, (1, 2)), (TOPIC_POSE, (1,))):
            for stamp in stamps:
                if topic == TOPIC_IMAGE:
                    m = depth_to_image_msg(np.ones((4, 4), np.float32), stamp)
                elif topic == TOPIC_CAMERA_INFO:
                    m = intrinsics_to_camera_info(intr, stamp)
                else:
                    m = pose_to_transform_msg(np.eye(4), stamp)
                if topic not in conns:
                    conns[topic] = writer.add_connection(topic, m.__msgtype__, typestore=store)
                writer.write(conns[topic], stamp, store.serialize_cdr(m, m.__msgtype__))
    with pytest.warns(BagWarning, match="matching stamp"):
        frames = list(read_frames(tmp_path / "bag"))
    assert [f.stamp_ns for f in frames] == [1]
    with pytest.raises(BagError, match="matching stamp"):
        read_frames(tmp_path / "bag", strict=True)


def test_truncated_and_garbage_bags_raise_bag_error(tmp_path: Path) -> None:
    _write_bag(tmp_path / "good", _random_frames(6), "32FC1")
    mcap = next((tmp_path / "good").glob("*.mcap"))
    data = mcap.read_bytes()
    for fraction in (0.3, 0.9):
        cut = tmp_path / f"cut{fraction}"
        shutil.copytree(tmp_path / "good", cut)
        (cut / mcap.name).write_bytes(data[: int(len(data) * fraction)])
        for target in (cut, cut / mcap.name):
            with pytest.raises(BagError, match=str(target)):
                read_frames(target)
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(np.random.default_rng(0).bytes(4096))
    with pytest.raises(BagError, match="garbage.mcap"):
        read_frames(garbage)
    not_a_bag = tmp_path / "dir"
    not_a_bag.mkdir()
    (not_a_bag / "metadata.yaml").write_text("this: [is not, a rosbag2")
    with pytest.raises(BagError, match="dir"):
        read_frames(not_a_bag)
    with pytest.raises(FileNotFoundError):
        read_frames(tmp_path / "missing")
    with pytest.raises(BagError, match="exists"):
        BagWriter(tmp_path / "good").open()


def test_integrate_command_matches_in_process(scene: dict, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    intr = scene["intrinsics"]
    pairs = list(zip(scene["depths"][:3], scene["poses"][:3], strict=True))
    quantized = [np.round(d * 1000.0) / 1000.0 for d, _ in pairs]
    bag32, bag16 = tmp_path / "bag32", tmp_path / "bag16"
    _write_bag(bag32, [(i * 10**8, d, intr, p) for i, (d, p) in enumerate(pairs)], "32FC1")
    quantized_frames = [
        (i * 10**8, q.astype(np.float32), intr, p) for i, (q, (_, p)) in enumerate(zip(quantized, pairs, strict=True))
    ]
    _write_bag(bag16, quantized_frames, "16UC1")
    assert cli.main(["integrate", "--bag", str(bag32), "--out", str(tmp_path / "g32.npz")]) == 0
    out = capsys.readouterr().out
    assert "frames read: 3" in out and "unknown:" in out and "occupied:" in out and "time:" in out
    expected = TsdfIntegrator(ORIGIN, SHAPE, VOXEL)
    for depth, pose in pairs:
        expected.integrate(depth, intr, pose)
    grid, origin, resolution = load_grid(tmp_path / "g32.npz")
    assert np.array_equal(grid, expected.ternary())
    assert np.array_equal(origin, ORIGIN) and resolution == VOXEL
    # 16UC1 bag == 32FC1 bag of the same millimetre depths
    bag32q = tmp_path / "bag32q"
    _write_bag(bag32q, quantized_frames, "32FC1")
    grids = []
    for bag in (bag16, bag32q):
        assert cli.main(["integrate", "--bag", str(bag), "--out", str(tmp_path / f"{bag.name}.npz")]) == 0
        grids.append(load_grid(tmp_path / f"{bag.name}.npz")[0])
    assert np.array_equal(grids[0], grids[1])
    # a smaller box with another origin
    args = ["--origin", "0.2", "0.2", "0.0", "--shape", "40", "30", "20", "--voxel", "0.02"]
    assert cli.main(["integrate", "--bag", str(bag32), "--out", str(tmp_path / "small.npz"), *args]) == 0
    small, origin, resolution = load_grid(tmp_path / "small.npz")
    assert small.shape == (40, 30, 20) and np.allclose(origin, [0.2, 0.2, 0.0]) and resolution == 0.02
    assert (small != UNKNOWN).any()
    # errors are reported, not raised
    assert cli.main(["integrate", "--bag", str(tmp_path / "nope"), "--out", str(tmp_path / "x.npz")]) == 2


def test_tsdf_grid_matches_a_generated_3dt_world() -> None:
    from nbv_prob_cnn.bench.fusion import tsdf_quality

    quality = tsdf_quality(seed=1000, views=6)
    assert quality["empty_cells"] > 100_000 and quality["seen_surface_cells"] > 5_000
    assert quality["empty_precision"] >= 0.95
    assert quality["surface_recall"] >= 0.90


# ------------------------------------------------------------------ messages (pure: no rclpy)
def test_messages_module_imports_no_rclpy() -> None:
    import subprocess
    import sys

    code = "import sys, nbv_prob_cnn.perception.messages; print('rclpy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_stamp_conversion_is_exact() -> None:
    from types import SimpleNamespace

    from nbv_prob_cnn.perception.messages import stamp_ns, stamp_parts

    assert stamp_parts(1_700_000_000_123_456_789) == (1_700_000_000, 123_456_789)
    assert stamp_parts(999_999_999) == (0, 999_999_999)
    assert stamp_ns(SimpleNamespace(sec=3, nanosec=5)) == 3_000_000_005
    header = depth_to_image_msg(np.zeros((2, 2), np.float32), 42_000_000_017).header.stamp
    assert (header.sec, header.nanosec) == (42, 17)
    with pytest.raises(ValueError, match=">= 0"):
        stamp_parts(-1)


def _paired(image=None, info=None, pose=None, stamp: int = 5_000_000_000):
    from nbv_prob_cnn.perception.messages import PairedFrame

    intrinsics = Intrinsics.from_hfov(8, 6, 60.0)
    if image is None:
        image = depth_to_image_msg(np.full((6, 8), 0.6, np.float32), stamp, "16UC1")
    if info is None:
        info = intrinsics_to_camera_info(intrinsics, stamp)
    if pose is None:
        pose = pose_to_transform_msg(np.eye(4), stamp)
    return PairedFrame(stamp, image, info, pose)


def test_decode_frame_gives_rep118_depth_and_a_reason_for_each_rejection() -> None:
    from nbv_prob_cnn.perception.messages import DropReason, FrameRejectedError, decode_frame

    # 16UC1 millimetres -> metres, 0 = no return; 32FC1 metres, NaN kept (no return)
    mm = np.array([[600, 0], [1500, 65535]], np.uint16)
    frame = _paired(
        image=depth_to_image_msg(mm, 1, "16UC1"), info=intrinsics_to_camera_info(Intrinsics.from_hfov(2, 2, 60.0), 1)
    )
    depth, intrinsics, pose = decode_frame(frame)
    np.testing.assert_allclose(depth, [[0.6, 0.0], [1.5, 65.535]], rtol=1e-6)
    assert intrinsics.shape == (2, 2) and np.array_equal(pose, np.eye(4))
    metres = np.array([[0.5, np.nan]], np.float32)
    frame = _paired(
        image=depth_to_image_msg(metres, 1), info=intrinsics_to_camera_info(Intrinsics.from_hfov(2, 1, 60.0), 1)
    )
    depth, _, _ = decode_frame(frame)
    assert depth[0, 0] == pytest.approx(0.5) and np.isnan(depth[0, 1])

    store = typestore()
    rgb = _paired().image
    rgb.encoding = "rgb8"
    truncated = _paired().image
    truncated.data = truncated.data[:-2]
    nan_pose = _paired().pose
    nan_pose.transform.translation.x = float("nan")
    zero_quat = _paired().pose
    q = zero_quat.transform.rotation
    q.x = q.y = q.z = q.w = 0.0
    cases = [
        (_paired(image=rgb), DropReason.BAD_ENCODING, "rgb8"),
        (_paired(image=truncated), DropReason.SIZE_MISMATCH, "data bytes"),
        (_paired(info=intrinsics_to_camera_info(Intrinsics.from_hfov(16, 12, 60.0), 1)), DropReason.SIZE_MISMATCH,
         "does not match camera_info 16x12"),
        (_paired(pose=nan_pose), DropReason.NON_FINITE_POSE, "finite"),
        (_paired(pose=zero_quat), DropReason.NON_FINITE_POSE, "non-zero quaternion"),
    ]  # fmt: skip
    for frame, reason, text in cases:
        with pytest.raises(FrameRejectedError, match=text) as info:
            decode_frame(frame)
        assert info.value.reason == reason
    # the messages survive a CDR round trip unchanged (what the node receives)
    raw = store.serialize_cdr(_paired().image, "sensor_msgs/msg/Image")
    assert decode_frame(_paired(image=store.deserialize_cdr(raw, "sensor_msgs/msg/Image")))[0].shape == (6, 8)


def test_drop_counts_name_every_reason() -> None:
    from nbv_prob_cnn.perception.messages import DropCounts, DropReason

    counts = DropCounts()
    assert set(counts.as_dict()) == {r.value for r in DropReason} and counts.total() == 0
    counts.add(DropReason.NO_POSE, 3)
    counts.add(DropReason.BAD_ENCODING)
    assert counts.as_dict()["no_pose"] == 3 and counts.total() == 4


def test_stamp_sync_pairs_by_stamp_within_tolerance() -> None:
    from nbv_prob_cnn.perception.messages import DropReason, StampSync

    sync = StampSync(tolerance_ns=10_000_000)  # 10 ms
    frames, overflow = sync.add_image(1_000_000_000, "image1", now=0.0)
    assert frames == [] and overflow == []
    assert sync.add_info(1_000_000_000, "info1") == []
    assert sync.add_pose(1_020_000_000, "pose_far") == []  # 20 ms off: not a partner
    (frame,) = sync.add_pose(1_008_000_000, "pose_near")  # 8 ms off: paired as soon as it is there
    assert (frame.stamp_ns, frame.image, frame.info, frame.pose) == (1_000_000_000, "image1", "info1", "pose_near")
    # the nearest pose wins when several are within the tolerance
    sync = StampSync(tolerance_ns=10_000_000)
    sync.add_info(2_000_000_000, "info")
    sync.add_pose(1_995_000_000, "pose_a")
    sync.add_pose(2_002_000_000, "pose_b")
    (frame,), _ = sync.add_image(2_000_000_000, "image", now=0.0)
    assert (frame.stamp_ns, frame.image, frame.info, frame.pose) == (2_000_000_000, "image", "info", "pose_b")
    # an image whose pose is too old (outside the tolerance) waits, then expires with a reason
    frames, _ = sync.add_image(3_000_000_000, "image3", now=10.0)
    assert frames == []
    assert sync.expire(now=10.5, timeout_s=1.0) == []
    ((stamp, kind, reason),) = sync.expire(now=11.5, timeout_s=1.0)
    assert stamp == 3_000_000_000 and kind == DropReason.NO_POSE
    assert "no pose within ±0.01 s (nearest is -0.998 s away)" in reason and "camera_info" in reason
    assert sync.images == {}
