"""``nbv import-rgbd``: TUM RGB-D and 7-Scenes folders (written here) into depth-camera bags (issue 34, item 1)."""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from nbv_prob_cnn.cli import main
from nbv_prob_cnn.perception.bags import bag_topics, read_frames, read_raw_messages
from nbv_prob_cnn.perception.recordings import (
    SYNTHETIC_START_NS,
    TUM_INTRINSICS,
    RecordingError,
    read_7scenes,
    read_tum,
    up_rotation,
)
from nbv_prob_cnn.perception.rgbd_import import import_recording

SCENES = Path(__file__).resolve().parents[3] / "shared" / "data" / "rgbd" / "7scenes_redkitchen"
W, H = 8, 6
K = (5.0, 5.0, 3.5, 2.5)  # intrinsics of the tiny test images


def write_png(path: Path, pixels: np.ndarray) -> None:
    Image.fromarray(np.asarray(pixels, dtype=np.uint16)).save(path)


def depth_pattern(seed: int, scale: float) -> np.ndarray:
    """A depth image (metres in 0.5 .. 3 m, some holes) written in ``scale`` units per metre."""
    rng = np.random.default_rng(seed)
    metres = rng.uniform(0.5, 3.0, (H, W))
    metres[rng.random((H, W)) < 0.2] = 0.0
    return np.round(metres * scale).astype(np.uint16)


def quat_z(deg: float) -> tuple[float, float, float, float]:
    half = math.radians(deg) / 2
    return (0.0, 0.0, math.sin(half), math.cos(half))


# ------------------------------------------------------------------------------- TUM layout
@pytest.fixture
def tum(tmp_path) -> Path:
    """Four depth images at 1.000, 1.033, 1.067, 1.500 s; ground truth every 10 ms from 0.99 to 1.08 s,
    rotating 10 deg about z per sample: the last image has no pose within 0.02 s."""
    root = tmp_path / "tum"
    (root / "depth").mkdir(parents=True)
    lines = ["# depth maps", "# timestamp filename"]
    for i, stamp in enumerate((1.000, 1.033, 1.067, 1.500)):
        name = f"depth/{stamp:.6f}.png"
        write_png(root / name, depth_pattern(i, 5000.0))
        lines.append(f"{stamp:.6f} {name}")
    (root / "depth.txt").write_text("\n".join(lines) + "\n")
    truth = ["# ground truth trajectory", "# timestamp tx ty tz qx qy qz qw"]
    for j in range(10):
        stamp = 0.99 + 0.01 * j
        q = quat_z(10.0 * j)
        truth.append(f"{stamp:.4f} {0.1 * j:.4f} 0.5 1.5 {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}")
    (root / "groundtruth.txt").write_text("\n".join(truth) + "\n")
    return root


def test_tum_frames_take_the_nearest_pose_within_the_tolerance(tum):
    recording = read_tum(tum, K, (W, H))
    assert recording.unmatched == 1  # 1.500 s: nearest pose 1.08 s
    assert [f.stamp_ns for f in recording.frames] == [1_000_000_000, 1_033_000_000, 1_067_000_000]
    # nearest ground truth: 1.00 (j=1), 1.03 (j=4), 1.07 (j=8)
    for frame, j in zip(recording.frames, (1, 4, 8), strict=True):
        c, s = math.cos(math.radians(10.0 * j)), math.sin(math.radians(10.0 * j))
        np.testing.assert_allclose(frame.pose[:3, :3], [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=1e-8)
        np.testing.assert_allclose(frame.pose[:3, 3], [0.1 * j, 0.5, 1.5], atol=1e-12)
        assert frame.pose_source.endswith(f"groundtruth.txt line {j + 3}")
    k = recording.intrinsics
    assert (k.fx, k.fy, k.cx, k.cy) == K and (k.width, k.height) == (W, H)
    # without intrinsics: TUM's published ones, for 640x480 images
    with pytest.raises(RecordingError, match="image is 8x6 pixels, the intrinsics are 640x480"):
        read_tum(tum)
    assert TUM_INTRINSICS == (525.0, 525.0, 319.5, 239.5)
    # a looser tolerance matches the last image too
    assert read_tum(tum, K, (W, H), tolerance_s=0.5).unmatched == 0


def test_tum_bag_holds_millimetres_and_the_poses(tum, tmp_path, capsys):
    bag = tmp_path / "tum.bag"
    code = main(["import-rgbd", "--format", "tum", str(tum), "--out", str(bag), "--image-size", str(W), str(H),
                 "--intrinsics", "5", "5", "3.5", "2.5"])  # fmt: skip
    assert code == 0
    out = capsys.readouterr().out
    assert "wrote 3 frame(s)" in out and "1 depth image(s) without a pose (left out)" in out
    assert "world frame kept as recorded" in out
    frames = list(read_frames(bag))
    assert len(frames) == 3
    for i, (frame, j) in enumerate(zip(frames, (1, 4, 8), strict=True)):
        raw = depth_pattern(i, 5000.0)
        # 5000 units per metre -> millimetres, rounded, read back in metres
        np.testing.assert_allclose(frame.depth_m, np.round(raw / 5.0) / 1000.0, atol=1e-6)
        assert np.array_equal(frame.depth_m == 0, raw == 0)
        assert frame.intrinsics.fx == 5.0 and frame.intrinsics.cx == 3.5
        np.testing.assert_allclose(frame.pose_4x4[:3, 3], [0.1 * j, 0.5, 1.5], atol=1e-9)
    # what bag_replay reads: the camera's two topics and the poses on /tf, every message valid
    assert set(bag_topics(bag)) == {"/camera/depth/image", "/camera/depth/camera_info", "/tf"}
    assert sum(1 for _ in read_raw_messages(bag)) == 9


def test_every_and_max_frames(tum, tmp_path):
    recording = read_tum(tum, K, (W, H), tolerance_s=0.5)
    summary = import_recording(recording, tmp_path / "b1", every=2)
    assert (summary.written, summary.skipped_by_every, summary.beyond_max_frames) == (2, 2, 0)
    assert [f.stamp_ns for f in read_frames(tmp_path / "b1")] == [1_000_000_000, 1_067_000_000]
    summary = import_recording(recording, tmp_path / "b2", every=1, max_frames=3)
    assert (summary.written, summary.skipped_by_every, summary.beyond_max_frames) == (3, 0, 1)
    with pytest.raises(ValueError, match="every: must be >= 1"):
        import_recording(recording, tmp_path / "b3", every=0)
    assert not (tmp_path / "b3").exists()


def test_up_turns_the_world(tum, tmp_path):
    # a hand-worked case: up = -y; the rotation by +90 deg about x takes -y to +z, y to -z, keeps x
    rot = up_rotation((0.0, -2.0, 0.0))
    np.testing.assert_allclose(rot[:3, :3], [[1, 0, 0], [0, 0, 1], [0, -1, 0]], atol=1e-12)
    np.testing.assert_allclose(up_rotation((0, 0, -1))[:3, :3] @ [0, 0, -1], [0, 0, 1])
    np.testing.assert_array_equal(up_rotation((0, 0, 3)), np.eye(4))
    u = np.array([0.3, -0.5, 0.8])
    np.testing.assert_allclose(up_rotation(u)[:3, :3] @ (u / np.linalg.norm(u)), [0, 0, 1], atol=1e-12)
    with pytest.raises(ValueError, match="non-zero 3-vector"):
        up_rotation((0, 0, 0))

    recording = read_tum(tum, K, (W, H))
    summary = import_recording(recording, tmp_path / "up", up=(0.0, -1.0, 0.0))
    assert summary.up_angle_deg == pytest.approx(90.0)
    for frame, recorded in zip(read_frames(tmp_path / "up"), recording.frames, strict=True):
        np.testing.assert_allclose(frame.pose_4x4, rot @ recorded.pose, atol=1e-9)
        # recorded position (x, 0.5, 1.5) -> (x, 1.5, -0.5)
        np.testing.assert_allclose(frame.pose_4x4[1:3, 3], [1.5, -0.5], atol=1e-9)


# ---------------------------------------------------------------------------- 7-Scenes layout
@pytest.fixture
def scenes(tmp_path) -> Path:
    root = tmp_path / "seq"
    root.mkdir()
    (root / "camera-intrinsics.txt").write_text("6 0 3.5\n0 6 2.5\n0 0 1\n")
    (root / "gravity-direction.txt").write_text("0\n1\n0\n")
    for number in (0, 5, 10):
        write_png(root / f"frame-{number:06d}.depth.png", depth_pattern(number, 1000.0))
        pose = np.eye(4)
        pose[:3, :3] += 2e-4 * np.array([[1, 0, 0], [0, -1, 0], [0, 0, 1]])  # the rounding of real files
        pose[:3, 3] = (0.01 * number, 0.0, 0.0)
        np.savetxt(root / f"frame-{number:06d}.pose.txt", pose)
    return root


def test_7scenes_frames_stamps_and_gravity(scenes, tmp_path):
    recording = read_7scenes(scenes, image_size=(W, H))
    assert [f.stamp_ns - SYNTHETIC_START_NS for f in recording.frames] == [0, 166_666_667, 333_333_333]
    assert recording.intrinsics.fx == 6.0 and recording.intrinsics.cy == 2.5
    np.testing.assert_array_equal(recording.gravity, [0.0, 1.0, 0.0])
    np.testing.assert_allclose(recording.frames[0].pose, np.eye(4), atol=1e-15)  # re-orthonormalised
    # 65535 (the original files' "no return") becomes 0
    pixels = depth_pattern(5, 1000.0)
    pixels[0, 0] = 65535
    write_png(scenes / "frame-000005.depth.png", pixels)
    code = main(["import-rgbd", "--format", "7scenes", str(scenes), "--out", str(tmp_path / "s.bag"),
                 "--image-size", str(W), str(H)])  # fmt: skip
    assert code == 0
    frames = list(read_frames(tmp_path / "s.bag"))
    assert frames[1].depth_m[0, 0] == 0.0
    # default --up: minus gravity -> +z; gravity +y, so the camera's y axis (down) now points along -z
    np.testing.assert_allclose(frames[0].pose_4x4[:3, :3] @ [0, 1, 0], [0, 0, -1], atol=1e-12)


# ------------------------------------------------------------------------- bad input, either layout
def removed(name: str) -> Callable[[Path], None]:
    """Damage to a recording folder: the file ``name`` deleted."""
    return lambda root: (root / name).unlink()


def line_replaced(name: str, number: int, text: str) -> Callable[[Path], None]:
    """Damage to a recording folder: line ``number`` (from 1) of the text file ``name`` replaced by ``text``."""

    def damage(root: Path) -> None:
        path = root / name
        lines = path.read_text().splitlines()
        lines[number - 1] = text
        path.write_text("\n".join(lines) + "\n")

    return damage


def rewritten(name: str, text: str) -> Callable[[Path], None]:
    """Damage to a recording folder: the text file ``name`` holding only ``text``."""
    return lambda root: (root / name).write_text(text)


def png_written(name: str, pixels: np.ndarray) -> Callable[[Path], None]:
    """Damage to a recording folder: the depth image ``name`` replaced by 16-bit ``pixels``."""
    return lambda root: write_png(root / name, pixels)


#: (layout, damage to the test's folder of that layout, what the error says)
BAD_INPUT = [
    ("tum", removed("depth.txt"), "depth.txt: no such file"),
    ("tum", removed("groundtruth.txt"), "groundtruth.txt: no such file"),
    ("tum", removed("depth/1.033000.png"), "depth.txt line 4: no such depth image"),
    ("7scenes", removed("frame-000005.pose.txt"), "frame-000005.depth.png: no matching frame-000005.pose"),
    ("7scenes", removed("frame-000010.depth.png"), "frame-000010.pose.txt: no matching frame-000010.depth"),
    ("tum", line_replaced("groundtruth.txt", 4, "1.0 0 0 0 0 0 0"), "groundtruth.txt line 4: expected 8"),
    ("tum", line_replaced("groundtruth.txt", 5, "1.0 nan 0 0 0 0 0 1"), "groundtruth.txt line 5: NaN"),
    ("tum", line_replaced("groundtruth.txt", 6, "1.01 0 0 0 0 0 0 2"), "line 6: quaternion"),
    ("tum", line_replaced("depth.txt", 3, "1.0"), "depth.txt line 3: expected 'timestamp filename'"),
    ("7scenes", line_replaced("frame-000005.pose.txt", 2, "0 1 0 inf"), "frame-000005.pose.txt line 2: NaN"),
    ("7scenes", line_replaced("frame-000005.pose.txt", 3, "0 0 1"), "frame-000005.pose.txt line 3: expected 4"),
    ("7scenes", line_replaced("frame-000005.pose.txt", 1, "1.5 0 0 0"), "frame-000005.pose.txt: the rotation"),
    ("7scenes", line_replaced("frame-000005.pose.txt", 1, "-1 0 0 0"), "a reflection"),
    ("7scenes", rewritten("camera-intrinsics.txt", "6 0 3.5\n0 6 2.5\n"), "camera-intrinsics.txt: expected 3"),
    ("7scenes", rewritten("camera-intrinsics.txt", "6 0 30\n0 6 2.5\n0 0 1\n"), "principal point (30, 2.5)"),
    ("7scenes", rewritten("gravity-direction.txt", "0 0\n"), "gravity-direction.txt: expected 3"),
    ("tum", png_written("depth/1.067000.png", np.zeros((H + 1, W))), "image is 8x7 pixels"),
    ("7scenes", png_written("frame-000010.depth.png", np.zeros((H, W + 2))), "image is 10x6 pixels"),
    ("tum", lambda r: Image.fromarray(np.zeros((H, W), np.uint8)).save(r / "depth" / "1.000000.png"), "8-bit image"),
    ("tum", lambda r: (r / "depth" / "1.000000.png").write_bytes(b"not a png"), "not a readable PNG"),
]
#: layout -> (the fixture writing its test folder, its reader, the import-rgbd options it needs besides the image size)
LAYOUTS = {
    "tum": ("tum", lambda root: read_tum(root, K, (W, H)), ["--intrinsics", *(str(v) for v in K)]),
    "7scenes": ("scenes", lambda root: read_7scenes(root, image_size=(W, H)), []),
}


@pytest.mark.parametrize(("layout", "damage", "message"), BAD_INPUT)
def test_bad_input_names_the_file(layout, damage, message, request, tmp_path, capsys):
    fixture, read, options = LAYOUTS[layout]
    root = request.getfixturevalue(fixture)
    damage(root)
    with pytest.raises(RecordingError, match=re.escape(message)):
        read(root)
    # the command says the same and writes nothing
    bag = tmp_path / "bad.bag"
    args = ["--image-size", str(W), str(H), *options]
    assert main(["import-rgbd", "--format", layout, str(root), "--out", str(bag), *args]) == 2
    assert message.split(":")[-1].strip()[:12] in capsys.readouterr().err
    assert not bag.exists()


def test_refuses_an_existing_bag_and_a_missing_folder(scenes, tmp_path, capsys):
    (tmp_path / "exists").mkdir()
    args = ["import-rgbd", "--format", "7scenes", str(scenes), "--image-size", str(W), str(H), "--out"]
    assert main([*args, str(tmp_path / "exists")]) == 2
    assert "exists already" in capsys.readouterr().err
    assert main(["import-rgbd", "--format", "tum", str(tmp_path / "nowhere"), "--out", str(tmp_path / "x")]) == 2
    assert "nowhere: no such folder" in capsys.readouterr().err


@pytest.mark.skipif(not SCENES.is_dir(), reason=f"the shared 7-Scenes recording is absent ({SCENES})")
def test_the_shared_recording_imports(tmp_path):
    recording = read_7scenes(SCENES)
    assert len(recording.frames) == 200
    summary = import_recording(recording, tmp_path / "kitchen", every=10, up=-recording.gravity)
    assert summary.written == 20
    frames = list(read_frames(tmp_path / "kitchen"))
    assert len(frames) == 20
    k = frames[0].intrinsics
    assert (k.width, k.height, k.fx, k.cx, k.cy) == (640, 480, 585.0, 320.0, 240.0)
    # gravity now points down (-z) in the bag's world
    rot = up_rotation(-recording.gravity)[:3, :3]
    np.testing.assert_allclose(rot @ recording.gravity, [0, 0, -1], atol=1e-12)
    raw = np.asarray(Image.open(recording.frames[10].depth_path))
    np.testing.assert_allclose(frames[1].depth_m, raw / 1000.0, atol=1e-6)
    assert 0.85 < summary.valid_fraction < 0.95  # the README: about 11 % of the pixels have no return
