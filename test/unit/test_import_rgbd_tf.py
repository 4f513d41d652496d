"""``nbv import-rgbd`` writes the poses on ``/tf``, as a robot's recording has them, and the grid that
``nbv integrate`` fuses from such a bag is the grid of the same frames posed directly (and that of the
same frames on ``/camera/pose``, the simulated bags' layout), cell for cell."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from nbv_prob_cnn.cli import main
from nbv_prob_cnn.perception.bags import (
    TOPIC_CAMERA_INFO,
    TOPIC_IMAGE,
    TOPIC_TF,
    BagWarning,
    BagWriter,
    bag_pose_source,
    bag_topics,
    read_frames,
    read_raw_messages,
    typestore,
)
from nbv_prob_cnn.perception.recordings import depth_mm, read_7scenes, read_depth_png, up_rotation
from nbv_prob_cnn.perception.rgbd_import import default_up
from nbv_prob_cnn.perception.tsdf import TsdfIntegrator, load_grid

pytest.importorskip("open3d")

WIDTH, HEIGHT = 32, 24
VOXEL = 0.05


@pytest.fixture
def kitchen_corner(tmp_path) -> Path:
    """A 7-Scenes folder: four 32x24 views of a tilted wall 1.2-2.2 m away (a few holes, one 65535
    "no return"), the camera turning 5 deg about its y axis and moving 4 cm per frame, gravity +y."""
    root = tmp_path / "corner"
    root.mkdir()
    (root / "camera-intrinsics.txt").write_text("20 0 15.5\n0 20 11.5\n0 0 1\n")
    (root / "gravity-direction.txt").write_text("0.1\n0.99\n0\n")
    u, v = np.meshgrid(np.arange(WIDTH), np.arange(HEIGHT))
    for number in range(4):
        mm = 1200.0 + 30.0 * u + 5.0 * v + 10.0 * number
        mm[(u * 7 + v * 3 + number) % 11 == 0] = 0
        mm[0, 0] = 65535
        Image.fromarray(mm.astype(np.uint16)).save(root / f"frame-{number:06d}.depth.png")
        a = math.radians(5.0 * number)
        pose = np.eye(4)
        pose[:3, :3] = [[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]]
        pose[:3, 3] = (0.04 * number, 0.0, 0.01 * number)
        np.savetxt(root / f"frame-{number:06d}.pose.txt", pose)
    return root


def test_imported_poses_are_on_tf_stamped_as_the_images(kitchen_corner, tmp_path, capsys):
    bag = tmp_path / "corner.bag"
    args = ["import-rgbd", "--format", "7scenes", str(kitchen_corner), "--out", str(bag)]
    assert main([*args, "--image-size", str(WIDTH), str(HEIGHT)]) == 0
    assert "wrote 4 frame(s)" in capsys.readouterr().out
    # one source of truth: no /camera/pose
    assert bag_topics(bag) == {
        TOPIC_IMAGE: ("sensor_msgs/msg/Image", 4),
        TOPIC_CAMERA_INFO: ("sensor_msgs/msg/CameraInfo", 4),
        TOPIC_TF: ("tf2_msgs/msg/TFMessage", 4),
    }
    assert bag_pose_source(bag) == "tf"
    store = typestore()
    messages = [store.deserialize_cdr(m.data, m.msgtype) for m in read_raw_messages(bag)]
    transforms = [m.transforms for m in messages[0::3]]
    images = messages[1::3]
    for transforms_of_frame, image in zip(transforms, images, strict=True):
        (transform,) = transforms_of_frame  # one transform per /tf message
        assert transform.header.frame_id == "world" and transform.child_frame_id == image.header.frame_id
        assert image.header.frame_id == "camera_optical" and image.encoding == "16UC1"
        assert transform.header.stamp == image.header.stamp
    # the poses read back are the recording's, turned z-up (minus gravity)
    recording = read_7scenes(kitchen_corner, image_size=(WIDTH, HEIGHT))
    turn = up_rotation(default_up(recording))
    for frame, recorded in zip(read_frames(bag), recording.frames, strict=True):
        assert frame.stamp_ns == recorded.stamp_ns
        np.testing.assert_allclose(frame.pose_4x4, turn @ recorded.pose, atol=1e-12)


def test_integrate_of_the_imported_bag_is_the_grid_of_the_frames_posed_directly(kitchen_corner, tmp_path, capsys):
    imported = tmp_path / "imported"
    args = ["import-rgbd", "--format", "7scenes", str(kitchen_corner), "--image-size", str(WIDTH), str(HEIGHT)]
    assert main([*args, "--out", str(imported)]) == 0
    # the same frames posed directly (no bag), and written with their poses on /camera/pose
    recording = read_7scenes(kitchen_corner, image_size=(WIDTH, HEIGHT))
    turn = up_rotation(default_up(recording))
    direct = TsdfIntegrator(origin_m=np.zeros(3), shape_cells=None, voxel_size_m=VOXEL)
    with BagWriter(tmp_path / "by_topic") as by_topic:
        for frame in recording.frames:
            mm = depth_mm(recording, read_depth_png(frame.depth_path, recording.intrinsics))
            direct.integrate(mm.astype(np.float32) / np.float32(1000.0), recording.intrinsics, turn @ frame.pose)
            by_topic.write_frame(frame.stamp_ns, mm, recording.intrinsics, turn @ frame.pose, encoding="16UC1")
    expected = direct.save(tmp_path / "direct.npz")
    expected_origin, _ = direct.grid_box()
    grids = {}
    for name in ("imported", "by_topic"):
        out = tmp_path / f"{name}.npz"
        capsys.readouterr()
        assert main(["integrate", "--bag", str(tmp_path / name), "--voxel", str(VOXEL), "--bounds", "auto",
                     "--out", str(out)]) == 0  # fmt: skip
        printed = capsys.readouterr().out
        assert "frames read: 4 (poses from " + ("/tf in 'world')" if name == "imported" else "/camera/pose)") in printed
        grids[name] = load_grid(out)
    for name, (grid, origin, resolution) in grids.items():
        assert np.array_equal(grid, expected), f"{name}: {np.count_nonzero(grid != expected)} cells differ"
        np.testing.assert_allclose(origin, expected_origin, atol=1e-12)
        assert resolution == VOXEL
    occupied, empty = int(np.count_nonzero(expected == 1)), int(np.count_nonzero(expected == 0))
    assert occupied > 50 and empty > 500, (occupied, empty)  # the wall and the space in front of it
    # a fixed frame that the bag's TF does not hold poses nothing, says so and fails without a grid
    with pytest.warns(BagWarning, match=r"4 image\(s\) without a transform from 'map' in /tf"):
        assert (
            main(["integrate", "--bag", str(imported), "--fixed-frame", "map", "--out", str(tmp_path / "m.npz")]) == 2
        )
    err = capsys.readouterr().err
    assert f"--bag {imported}: no depth image could be posed (poses from /tf in 'map')" in err, err
    assert not (tmp_path / "m.npz").exists()
