"""The robot rendered into depth images and filtered out of them (no ROS), on a one-box robot
whose images can be worked out by hand, and the joint-state pairing of the self-filter."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pinocchio")

from nbv_prob_cnn.arm.robot import RobotModel, robot_config  # noqa: E402
from nbv_prob_cnn.basics.camera import look_rotation  # noqa: E402
from nbv_prob_cnn.perception.depth_camera import DepthCamera, Intrinsics  # noqa: E402

#: A robot of one 0.2 m cube sliding along world x (prismatic joint "slide"); the collision box
#: is 1 cm larger on each side than the visual one, as collision bodies enclose visual meshes.
SLIDER_URDF = """<?xml version="1.0"?>
<robot name="slider">
  <link name="base"/>
  <link name="block">
    <visual><geometry><box size="0.2 0.2 0.2"/></geometry></visual>
    <collision><geometry><box size="0.22 0.22 0.22"/></geometry></collision>
  </link>
  <joint name="slide" type="prismatic">
    <parent link="base"/><child link="block"/><axis xyz="1 0 0"/>
    <limit lower="-1.0" upper="1.0" effort="10" velocity="1"/>
  </joint>
</robot>
"""
EYE_X = 2.0  # the camera at (2, 0, 0) looks along -x at the block; a wall at x = -1 behind it
WALL_X = -1.0


@pytest.fixture(scope="module")
def slider(tmp_path_factory) -> RobotModel:
    path = tmp_path_factory.mktemp("slider") / "slider.urdf"
    path.write_text(SLIDER_URDF)
    return RobotModel(robot_config(str(path), base_xyz=(0.0, 0.0, 0.0), camera_parent="block"))


@pytest.fixture(scope="module")
def wall():
    import trimesh

    box = trimesh.creation.box(extents=(0.02, 6.0, 6.0))
    box.apply_translation((WALL_X - 0.01, 0.0, 0.0))
    return box


def looking_along_minus_x() -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = look_rotation(np.array([-1.0, 0.0, 0.0]))
    pose[:3, 3] = (EYE_X, 0.0, 0.0)
    return pose


def hand_worked_depth(intrinsics: Intrinsics, face_x: float, half_side: float) -> tuple[np.ndarray, np.ndarray]:
    """Expected z-depth of the block's front face (a square of ``half_side`` at ``x = face_x``
    facing the camera) and of the wall, with the pixels of the face; pixels whose ray passes
    within 2 mm of the face's edge are left out (``None`` there)."""
    d_face, d_wall = EYE_X - face_x, EYE_X - WALL_X
    u = (np.arange(intrinsics.width) - intrinsics.cx) / intrinsics.fx
    v = (np.arange(intrinsics.height) - intrinsics.cy) / intrinsics.fy
    lateral = np.maximum(np.abs(u)[None, :], np.abs(v)[:, None]) * d_face  # offset from the axis on the face
    face = lateral < half_side - 0.002
    certain = face | (lateral > half_side + 0.002)
    return np.where(face, d_face, d_wall).astype(np.float32), certain


def test_robot_rendered_into_a_depth_image_matches_hand_worked_depths(slider, wall):
    from nbv_prob_cnn.arm.robot_scene import RobotScene

    intrinsics = Intrinsics.from_hfov(64, 48, 40.0)
    pose = looking_along_minus_x()
    scene = RobotScene(slider, "visual")
    camera = DepthCamera([wall], intrinsics)
    for slide in (0.0, 0.5, -0.3):
        q = np.array([slide])
        depth = camera.render(pose, occluders=[scene.scene(q)])
        expected, certain = hand_worked_depth(intrinsics, slide + 0.1, 0.1)
        assert certain.sum() > 0.9 * certain.size
        np.testing.assert_allclose(depth[certain], expected[certain], atol=1e-5)
        assert (expected[certain] < EYE_X - WALL_X).sum() > 20  # the block covers some pixels
        # the robot alone: the block's pixels, 0 elsewhere
        alone = scene.depth(q, intrinsics, pose)
        np.testing.assert_allclose(alone[certain], np.where(expected < EYE_X - WALL_X, expected, 0)[certain], atol=1e-5)
    # the scene is rebuilt when q changes and kept while it does not
    assert scene.rebuilds == 3
    same = scene.scene(np.array([-0.3]))
    assert scene.scene(np.array([-0.3])) is same and scene.rebuilds == 3
    with pytest.raises(ValueError, match="expected 1 joint positions"):
        scene.scene(np.array([0.0, 1.0]))
    with pytest.raises(ValueError, match="bodies"):
        RobotScene(slider, "meshes")


def test_occluders_keep_the_nearest_return_before_range_and_noise(slider, wall):
    from nbv_prob_cnn.arm.robot_scene import RobotScene
    from nbv_prob_cnn.perception.depth_camera import DepthNoise

    intrinsics = Intrinsics.from_hfov(32, 24, 40.0)
    pose = looking_along_minus_x()
    block = RobotScene(slider, "visual").scene(np.array([0.0]))
    # the wall lies beyond depth_max: only the block returns
    limited = DepthCamera([wall], intrinsics, depth_max=2.5).render(pose, occluders=[block])
    expected, certain = hand_worked_depth(intrinsics, 0.1, 0.1)
    np.testing.assert_allclose(limited[certain], np.where(expected < 2.5, expected, 0)[certain], atol=1e-5)
    # dropout noise applies to the block's pixels too (every pixel dropped)
    dropped = DepthCamera([wall], intrinsics, noise=DepthNoise(dropout=1.0)).render(pose, occluders=[block])
    assert not dropped.any()


def test_self_filter_removes_the_robot_and_keeps_what_is_in_front_of_it(slider, wall):
    import trimesh

    from nbv_prob_cnn.arm.robot_scene import RobotScene
    from nbv_prob_cnn.arm.self_filter import RobotSelfFilter

    intrinsics = Intrinsics.from_hfov(64, 48, 40.0)
    pose = looking_along_minus_x()
    q = np.array([0.2])
    # a thin plate 30 cm in front of the block covers its upper half (optical y < 0 is world z > 0)
    plate = trimesh.creation.box(extents=(0.01, 0.4, 0.2))
    plate.apply_translation((0.6, 0.0, 0.1 + 0.02))
    camera = DepthCamera([wall, plate], intrinsics)
    depth = camera.render(pose, occluders=[RobotScene(slider, "visual").scene(q)])
    block, certain = hand_worked_depth(intrinsics, 0.3, 0.1)
    plate_px = np.abs(depth - (EYE_X - 0.6 - 0.005)) < 1e-4
    block_px = (np.abs(depth - (EYE_X - 0.3)) < 1e-4) & certain
    assert block_px.sum() > 20 and plate_px.sum() > 20

    self_filter = RobotSelfFilter(slider, "collision", tolerance_m=0.02)
    mask = self_filter.mask(depth, q, intrinsics, pose)
    filtered = self_filter.filter(depth, q, intrinsics, pose)
    assert mask[block_px].all()  # every pixel seeing the block is the robot
    assert not mask[plate_px].any()  # the plate in front of it is not
    # nor the wall outside the collision box's silhouette (front face at x = 0.31, half side 0.11);
    # the wall inside it, around the smaller visual box, is masked: the filter errs towards removing
    collision, certain_collision = hand_worked_depth(intrinsics, 0.31, 0.11)
    wall_px = np.abs(depth - (EYE_X - WALL_X)) < 1e-4
    outside = certain_collision & (collision == EYE_X - WALL_X)
    assert not mask[wall_px & outside].any()
    assert mask[wall_px & certain_collision & ~outside].all() and (wall_px & ~outside).sum() > 4
    assert np.all(filtered[mask] == 0) and np.array_equal(filtered[~mask], depth[~mask])
    # measured 1.5 cm in front of the collision box (within the 2 cm tolerance): still the robot
    near = np.where(block_px, depth - 0.015 - 0.01, depth)
    assert self_filter.mask(near, q, intrinsics, pose)[block_px].all()
    # 3 cm in front of it: something else
    assert not self_filter.mask(np.where(block_px, depth - 0.04, depth), q, intrinsics, pose)[block_px].any()


def test_joint_state_configuration_names_bad_joints():
    robot = RobotModel()
    names = list(robot.joint_names)
    q = robot.joint_state_configuration(names[::-1], list(robot.reference_q[::-1]))
    np.testing.assert_array_equal(q, robot.reference_q)
    cases = [
        (["elbow", *names[1:]], "unknown joint names \\['elbow'\\], missing joints \\['panda_joint1'\\]"),
        (names[:-1], "missing joints \\['panda_finger_joint2'\\]"),
        ([*names, "extra"], "unknown joint names \\['extra'\\], missing joints \\[\\]"),
        ([*names, names[0]], "duplicate joint names \\['panda_joint1'\\]"),
    ]
    for bad, message in cases:
        with pytest.raises(ValueError, match=message):
            robot.joint_state_configuration(bad, [0.0] * len(bad))
    with pytest.raises(ValueError, match="9 joint names but 2 positions"):
        robot.joint_state_configuration(names, [0.0, 0.0])
    with pytest.raises(ValueError, match="non-finite"):
        robot.joint_state_configuration(names, [np.nan] * len(names))


def test_stamp_sync_waits_for_joint_states_when_required():
    from nbv_prob_cnn.perception.messages import DropReason, StampSync

    sync = StampSync(10_000_000, require_joints=True)
    assert sync.add_image(1_000_000_000, "image", now=0.0) == ([], [])
    assert sync.add_info(1_000_000_000, "info") == []
    assert sync.add_pose(1_002_000_000, "pose") == []  # still waiting for the joint states
    assert sync.add_joints(1_050_000_000, "far") == []  # 50 ms away: outside the tolerance
    frames = sync.add_joints(995_000_000, "joints")
    assert [(f.stamp_ns, f.pose, f.joints) for f in frames] == [(1_000_000_000, "pose", "joints")]
    # an image whose joint states never come is dropped for that reason, naming the nearest
    sync.add_image(2_000_000_000, "image", now=0.0)
    sync.add_info(2_000_000_000, "info")
    sync.add_pose(2_000_000_000, "pose")
    [(stamp, reason, text)] = sync.expire(now=5.0, timeout_s=1.0)
    assert stamp == 2_000_000_000 and reason == DropReason.NO_JOINT_STATES
    assert text == "no joint_states within ±0.01 s (nearest is -0.950 s away)"
    # joint states pair only once one at or after the image has come: a nearer one could follow
    sync.add_image(3_000_000_000, "image", now=10.0)
    sync.add_info(3_000_000_000, "info")
    sync.add_pose(3_000_000_000, "pose")
    assert sync.add_joints(2_992_000_000, "before") == []  # 8 ms before: within the tolerance, not settled
    [frame] = sync.add_joints(3_004_000_000, "after")  # 4 ms after: nearer
    assert frame.joints == "after"
    sync.add_image(4_000_000_000, "image", now=10.0)
    sync.add_info(4_000_000_000, "info")
    sync.add_pose(4_000_000_000, "pose")
    assert sync.add_joints(3_995_000_000, "before") == []
    [(stamp, reason, text)] = sync.expire(now=20.0, timeout_s=1.0)
    assert stamp == 4_000_000_000 and reason == DropReason.NO_JOINT_STATES
    assert text == "no joint_states stamped at or after the image (newest is -0.005 s away)"
    # without the requirement, frames pair as before and carry no joint states
    plain = StampSync(10_000_000)
    plain.add_image(1, "image", now=0.0)
    plain.add_info(1, "info")
    assert [f.joints for f in plain.add_pose(1, "pose")] == [None]


def test_both_bodies_filter_every_pixel_of_the_rendered_panda():
    """The Panda rendered with its visual meshes, filtered with its collision bodies alone and with
    both: the pybullet collision meshes leave a few silhouette pixels, the union none."""
    from nbv_prob_cnn.arm.robot_scene import RobotScene
    from nbv_prob_cnn.arm.self_filter import RobotSelfFilter

    robot = RobotModel()
    q = robot.reference_q
    intrinsics = Intrinsics.from_hfov(160, 120, 70.0)
    pose = np.eye(4)
    eye = np.array([0.9, 0.742, 0.8])
    pose[:3, :3] = look_rotation(np.array([0.0, 0.742, 0.35]) - eye)
    pose[:3, 3] = eye
    depth = RobotScene(robot, "visual").depth(q, intrinsics, pose)
    seen = depth > 0
    assert seen.sum() > 1000
    collision = RobotSelfFilter(robot, "collision").mask(depth, q, intrinsics, pose)
    both = RobotSelfFilter(robot, "both")
    assert len(both.scene.meshes) == len(robot.collision_model.geometryObjects) + len(
        robot.visual_model.geometryObjects
    )
    union = both.mask(depth, q, intrinsics, pose)
    assert np.all(union[seen])  # every arm pixel
    assert np.all(union[collision])  # a superset of the collision mask
    assert 0 < (seen & ~collision).sum() < 0.01 * seen.sum()  # what collision bodies alone leave
