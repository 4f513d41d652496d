"""Robot descriptions as a ROS graph carries them (no ROS): ``package://`` resolution, xacro,
the camera mounted in the description, joint states merged over partial messages."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from nbv_prob_cnn.arm.description import (
    find_package,
    mount_camera,
    place_root,
    read_description,
    resolve_package_uris,
    urdf_joints,
    urdf_root_link,
)
from nbv_prob_cnn.arm.joint_states import JointStateMerger
from nbv_prob_cnn.arm.robot import (
    DEFAULT_BASE_XYZ,
    DEFAULT_HAND_FROM_CAMERA_XYZ,
    RobotConfig,
    RobotModel,
    panda_urdf,
    translation,
)


def revolute_joint(name: str, parent: str, child: str, z: str, axis: str, velocity: str) -> str:
    """The URDF of the toy robots' joints: ``z`` m above ``parent``'s origin, turning about
    ``axis`` within ±1 rad at up to ``velocity`` rad/s."""
    return f"""<joint name="{name}" type="revolute">
    <parent link="{parent}"/><child link="{child}"/>
    <origin xyz="0 0 {z}" rpy="0 0 0"/><axis xyz="{axis}"/>
    <limit lower="-1" upper="1" velocity="{velocity}" effort="1"/>
  </joint>"""


TWO_LINK = f"""<?xml version="1.0"?>
<robot name="two_link">
  <link name="base"><visual><geometry><mesh filename="package://toy_description/meshes/base.stl"/></geometry></visual></link>
  <link name="arm"/>
  {revolute_joint("shoulder", "base", "arm", "0.5", "0 0 1", "2")}
</robot>
"""


def make_package(root: Path, name: str, manifest: bool = True) -> Path:
    folder = root / name
    (folder / "meshes").mkdir(parents=True)
    (folder / "meshes" / "base.stl").write_text("solid empty\nendsolid empty\n")
    if manifest:
        (folder / "package.xml").write_text(f"<package format='3'><name>{name}</name></package>")
    return folder


# -- package:// ----------------------------------------------------------------------------------
def test_package_uris_resolve_from_package_dirs_ament_prefix_and_ros_package_path(tmp_path):
    make_package(tmp_path / "dirs", "toy_description")
    expected = str((tmp_path / "dirs" / "toy_description").resolve()) + "/meshes/base.stl"
    # the package's parent folder, and the package's own folder, both work as package_dirs
    for entry in (tmp_path / "dirs", tmp_path / "dirs" / "toy_description"):
        text = resolve_package_uris(TWO_LINK, [str(entry)], env={})
        assert f'filename="{expected}"' in text and "package://" not in text
    # an ament prefix: <prefix>/share/<package>
    make_package(tmp_path / "prefix" / "share", "toy_description")
    text = resolve_package_uris(TWO_LINK, [], env={"AMENT_PREFIX_PATH": f"/nonexistent:{tmp_path / 'prefix'}"})
    assert str((tmp_path / "prefix" / "share" / "toy_description").resolve()) + "/meshes/base.stl" in text
    # ROS_PACKAGE_PATH entries
    make_package(tmp_path / "ros1", "toy_description", manifest=False)
    text = resolve_package_uris(TWO_LINK, [], env={"ROS_PACKAGE_PATH": str(tmp_path / "ros1")})
    assert str((tmp_path / "ros1" / "toy_description").resolve()) + "/meshes/base.stl" in text
    # package_dirs come first
    text = resolve_package_uris(TWO_LINK, [str(tmp_path / "dirs")], env={"ROS_PACKAGE_PATH": str(tmp_path / "ros1")})
    assert expected in text


def test_a_missing_package_is_an_error_naming_it_and_where_it_was_looked_for(tmp_path):
    with pytest.raises(ValueError, match=r"package 'toy_description' .*not found.*package_dirs .*elsewhere"):
        resolve_package_uris(TWO_LINK, [str(tmp_path / "elsewhere")], env={"AMENT_PREFIX_PATH": str(tmp_path)})
    with pytest.raises(ValueError, match="package 'toy_description'"):
        find_package("toy_description", [], env={})


def test_the_xarm6_of_pybullet_data_loads_with_its_package_meshes():
    pybullet_data = pytest.importorskip("pybullet_data")
    folder = Path(pybullet_data.getDataPath()) / "xarm"
    text = (folder / "xarm6_robot.urdf").read_text()
    assert "package://xarm_description/" in text
    with pytest.raises(ValueError, match="package 'xarm_description'"):
        read_description(text, package_dirs=[], env={})
    urdf = read_description(text, package_dirs=[str(folder)], env={})
    meshes = [m.split('"')[0] for m in urdf.split('<mesh filename="')[1:]]
    assert meshes and all(Path(m).is_file() for m in meshes)
    robot = RobotModel(RobotConfig(description=urdf, world_from_base=np.eye(4), camera_parent="link6",
                                   parent_from_camera=translation([0.0, 0.0, 0.05])))  # fmt: skip
    assert robot.joint_names == [f"joint{i}" for i in range(1, 7)]
    assert len(robot.collision_model.geometryObjects) >= 6


# -- xacro ---------------------------------------------------------------------------------------
XACRO = (
    """<?xml version="1.0"?>
<robot name="toy" xmlns:xacro="http://www.ros.org/wiki/xacro">
  <xacro:arg name="height" default="0.5"/>
  <xacro:property name="reach" value="0.25"/>
  <xacro:macro name="segment" params="name parent z">
    <link name="${name}"/>
    """
    + revolute_joint("${name}_joint", "${parent}", "${name}", "${z}", "0 1 0", "1")
    + """
  </xacro:macro>
  <link name="base"/>
  <xacro:segment name="upper" parent="base" z="$(arg height)"/>
  <xacro:segment name="lower" parent="upper" z="${2 * reach}"/>
</robot>
"""
)


def test_xacro_files_and_strings_expand_with_their_arguments(tmp_path):
    path = tmp_path / "toy.urdf.xacro"
    path.write_text(XACRO)
    for kwargs in ({"path": str(path)}, {"text": XACRO}):
        urdf = read_description(**kwargs, xacro_args={"height": "0.7"}, env={})
        joints = urdf_joints(urdf)
        assert [(j.name, j.parent, j.child) for j in joints] == [
            ("upper_joint", "base", "upper"), ("lower_joint", "upper", "lower"),
        ]  # fmt: skip
        robot = RobotModel(RobotConfig(description=urdf, world_from_base=np.eye(4), camera_parent="lower",
                                       parent_from_camera=np.eye(4)))  # fmt: skip
        # base → upper 0.7 m (the argument), upper → lower 2 × 0.25 m (the property), all joints at 0
        np.testing.assert_allclose(robot.camera_pose(np.zeros(2))[:3, 3], [0.0, 0.0, 1.2], atol=1e-12)
        # rotating the lower joint (about y) by 90° at zero upper joint leaves the tip on the axis
        q = np.array([math.pi / 2, 0.0])  # the upper joint swings the lower link 0.5 m along +x
        np.testing.assert_allclose(robot.camera_pose(q)[:3, 3], [0.5, 0.0, 0.7], atol=1e-12)
    with pytest.raises(ValueError, match="xacro failed"):
        read_description(text=XACRO.replace("${2 * reach}", "${2 * nowhere}"), env={})


# -- the camera and the base in the description ---------------------------------------------------
def test_a_description_with_the_camera_and_world_links_gives_the_parameterised_model():
    """What arm_sim publishes (the Panda with world → panda_link0 and panda_hand → camera_optical
    fixed joints) makes the same camera poses as the model built from the base and mount parameters."""
    text = mount_camera(panda_urdf()[0].read_text(), "panda_hand", translation(DEFAULT_HAND_FROM_CAMERA_XYZ),
                        "camera_optical", "world", translation(DEFAULT_BASE_XYZ))  # fmt: skip
    assert urdf_root_link(text) == "world"
    fixed = {(j.parent, j.child) for j in urdf_joints(text) if j.fixed}
    assert {("world", "panda_link0"), ("panda_hand", "camera_optical")} <= fixed
    config = RobotConfig(description=text, world_from_base=np.eye(4), camera_parent="camera_optical",
                         parent_from_camera=np.eye(4))  # fmt: skip
    from_description = RobotModel(config)
    from_parameters = RobotModel()
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.uniform(from_parameters.lower, from_parameters.upper)
        np.testing.assert_allclose(from_description.camera_pose(q), from_parameters.camera_pose(q), atol=1e-12)
    np.testing.assert_allclose(from_description.reference_q, from_parameters.reference_q)  # the Panda's ready pose


def test_place_root_moves_an_existing_world_root_by_the_base_pose():
    text = TWO_LINK.replace('<link name="arm"/>', '<link name="arm"/><link name="world"/>').replace(
        "</robot>", '<joint name="fix" type="fixed"><parent link="world"/><child link="base"/>'
        '<origin xyz="0.1 0 0" rpy="0 0 0"/></joint></robot>'
    )  # fmt: skip
    placed = place_root(text, "world", translation([1.0, 2.0, 3.0]))
    joint = [j for j in urdf_joints(placed) if j.name == "fix"]
    assert len(joint) == 1 and 'xyz="1.1 2.0 3.0"' in placed


# -- joint states ----------------------------------------------------------------------------------
def test_joint_states_merge_partial_messages_ignore_extra_names_and_name_the_missing():
    merger = JointStateMerger(["j1", "j2", "finger"])
    with pytest.raises(ValueError, match=r"no position received yet for joints \['j1', 'j2', 'finger'\]"):
        merger.configuration()
    assert merger.update(["j1", "j2", "conveyor"], [0.1, 0.2, 9.0]) == ["conveyor"]  # arm driver + an extra
    assert merger.missing() == ["finger"]
    with pytest.raises(ValueError, match=r"joints \['finger'\].*ignored names so far: \['conveyor'\]"):
        merger.configuration()
    merger.update(["finger", "drive_joint"], [0.04, 0.5])  # the gripper's own message
    np.testing.assert_array_equal(merger.configuration(), [0.1, 0.2, 0.04])
    merger.update(["j2"], [-0.3])  # a partial update keeps the others
    np.testing.assert_array_equal(merger.configuration(), [0.1, -0.3, 0.04])
    assert merger.ignored == {"conveyor", "drive_joint"}
    for names, positions, reason in (
        (["j1", "j1"], [0.0, 1.0], "duplicate joint names"),
        (["j1", "j2"], [0.0], "2 joint names but 1 positions"),
        (["j1", "j2"], [0.5, math.nan], r"non-finite positions for joints \['j2'\]"),
    ):
        with pytest.raises(ValueError, match=reason):
            merger.update(names, positions)
        np.testing.assert_array_equal(merger.configuration(), [0.1, -0.3, 0.04])  # a refused message changes nothing
    merger.update(["conveyor"], [math.nan])  # a non-finite value of a joint the model lacks does not matter
