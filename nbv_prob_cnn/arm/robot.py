"""The robot arm: a URDF loaded with pinocchio, placed on a base pose, with a camera on its hand.

Conventions:
    * Every pose is a 4×4 ``float64`` matrix in the *world* frame (the grid frame of 3DT:
      origin at the corner of cell 0, z up). ``world_from_base`` places the URDF's root link.
    * The camera frame is REP-103 optical (x right, y down, z forward), fixed on
      ``camera_parent`` (a URDF link) by ``parent_from_camera``.
    * A configuration ``q`` is the pinocchio configuration vector (``model.nq``, joint order of
      :attr:`RobotModel.joint_names`). Only revolute/prismatic joints are supported.

Default robot: the Franka Emika Panda URDF shipped by the ``pybullet`` package
(``pybullet_data/franka_panda``, Apache-2.0). Its ``package://meshes`` paths are rewritten to the
installed folder into a copy under the cache directory (``$NBV_CACHE_DIR`` or
``~/.cache/nbv_prob_cnn``), never into the repository.
"""

from __future__ import annotations

import hashlib
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nbv_prob_cnn.arm.joint_states import checked_joint_names
from nbv_prob_cnn.perception.depth_camera import check_pose
from nbv_prob_cnn.worlds import dataset_cache_dir

#: Base of the default Panda: beside the 3DT table (grid 1.48 × 1.48 × 1.11 m from the origin),
#: 10 cm before its x = 0 face, mid-way along y, at the height of the grid floor.
DEFAULT_BASE_XYZ: tuple[float, float, float] = (-0.10, 0.742, 0.0)
#: Camera on the Panda hand: 7 cm beside the fingers (hand +x), 5 cm along the approach axis,
#: looking along the approach axis (hand z = optical z), so the fingers stay out of the view.
DEFAULT_HAND_FROM_CAMERA_XYZ: tuple[float, float, float] = (0.07, 0.0, 0.05)
#: A collision-free "ready" configuration of the Panda (joints 1-7 in rad, fingers open in m).
PANDA_READY: dict[str, float] = {
    "panda_joint1": 0.0,
    "panda_joint2": -0.785,
    "panda_joint3": 0.0,
    "panda_joint4": -2.356,
    "panda_joint5": 0.0,
    "panda_joint6": 1.571,
    "panda_joint7": 0.785,
    "panda_finger_joint1": 0.04,
    "panda_finger_joint2": 0.04,
}


def translation(xyz: Sequence[float]) -> np.ndarray:
    """4×4 pure translation."""
    pose = np.eye(4)
    pose[:3, 3] = np.asarray(xyz, dtype=np.float64)
    return pose


def pose_from_xyz_rpy(xyz: Sequence[float], rpy: Sequence[float]) -> np.ndarray:
    """4×4 pose of a translation and URDF roll-pitch-yaw angles (``Rz(yaw) Ry(pitch) Rx(roll)``).

    Raises:
        ValueError: not three finite values each.
    """
    xyz_arr, rpy_arr = np.asarray(xyz, dtype=np.float64), np.asarray(rpy, dtype=np.float64)
    if xyz_arr.shape != (3,) or rpy_arr.shape != (3,) or not np.all(np.isfinite(np.r_[xyz_arr, rpy_arr])):
        raise ValueError(f"pose: expected 3 finite xyz and 3 finite rpy values, got {list(xyz)} and {list(rpy)}")
    (cr, cp, cy), (sr, sp, sy) = np.cos(rpy_arr), np.sin(rpy_arr)
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    rot_y = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rot_z = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    pose = translation(xyz_arr.tolist())
    pose[:3, :3] = rot_z @ rot_y @ rot_x
    return pose


def arm_cache_dir() -> Path:
    """``<NBV_CACHE_DIR or ~/.cache/nbv_prob_cnn>/arm``."""
    return dataset_cache_dir() / "arm"


def panda_urdf() -> tuple[Path, Path]:
    """The pybullet Panda URDF with absolute mesh paths: ``(urdf path in the cache, mesh folder)``.

    Raises:
        FileNotFoundError: the ``pybullet`` package (``pybullet_data``) is not installed.
    """
    try:
        import pybullet_data
    except ImportError:
        raise FileNotFoundError("robot: the default Panda needs the 'pybullet' package (pybullet_data)") from None
    folder = Path(pybullet_data.getDataPath()) / "franka_panda"
    source = folder / "panda.urdf"
    if not source.is_file():
        raise FileNotFoundError(f"robot: {source} not found in the installed pybullet_data")
    text = source.read_text().replace("package://meshes", str(folder / "meshes"))
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    target = arm_cache_dir() / f"panda_{digest}.urdf"
    if not target.is_file():
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = target.with_suffix(".tmp")
        tmp.write_text(text)
        tmp.replace(target)
    return target, folder


@dataclass(frozen=True)
class RobotConfig:
    """How to build a :class:`RobotModel` (all parameters of a robot description).

    Attributes:
        urdf_path: URDF file; ``None`` = the default Panda (unless ``description`` is given).
        package_dirs: folders that resolve ``package://`` mesh paths.
        description: URDF text (e.g. received on ``/robot_description``, resolved by
            :func:`~nbv_prob_cnn.arm.description.read_description`); wins over ``urdf_path``.
        world_from_base: 4×4 pose of the URDF root link in the world.
        camera_parent: URDF link carrying the camera.
        parent_from_camera: 4×4 pose of the optical frame on ``camera_parent``.
        reference: joint name → position of a known collision-free configuration; joints off the
            camera chain (fingers) keep these values; self-collision pairs in contact at this
            configuration are disabled (mesh approximations overlap at rest). ``None``: the
            Panda's ready pose for a robot with the Panda's joints, the middle of the limits otherwise.
    """

    urdf_path: str | None = None
    package_dirs: tuple[str, ...] = ()
    description: str | None = None
    world_from_base: np.ndarray = field(default_factory=lambda: translation(DEFAULT_BASE_XYZ))
    camera_parent: str = "panda_hand"
    parent_from_camera: np.ndarray = field(default_factory=lambda: translation(DEFAULT_HAND_FROM_CAMERA_XYZ))
    reference: Mapping[str, float] | None = None

    def cache_key(self) -> str:
        """Hash of everything that changes the kinematics and the map's IK seed (URDF text, base,
        camera mount, reference)."""
        digest = hashlib.sha256(self.urdf_file().read_bytes())
        for array in (self.world_from_base, self.parent_from_camera):
            digest.update(np.round(np.asarray(array, dtype=np.float64), 9).tobytes())
        digest.update(self.camera_parent.encode())
        digest.update(repr(sorted((self.reference or {}).items())).encode())  # the IK seed of the map
        return digest.hexdigest()[:20]

    def urdf_file(self) -> Path:
        """The URDF file the model is built from: ``urdf_path``, the default Panda's, or the
        ``description`` text written once into the cache (named by its hash)."""
        if self.description is not None:
            return description_file(self.description)
        return Path(self.urdf_path) if self.urdf_path else panda_urdf()[0]


def description_file(text: str) -> Path:
    """A URDF text as a file in the cache directory (pinocchio and the mesh loaders read files)."""
    target = arm_cache_dir() / f"description_{hashlib.sha256(text.encode()).hexdigest()[:16]}.urdf"
    if not target.is_file():
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = target.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(text)
        tmp.replace(target)
    return target


def robot_config(
    urdf_path: str = "",
    base_xyz: Sequence[float] = DEFAULT_BASE_XYZ,
    base_rpy: Sequence[float] = (0.0, 0.0, 0.0),
    camera_parent: str = "",
    camera_xyz: Sequence[float] = DEFAULT_HAND_FROM_CAMERA_XYZ,
    camera_rpy: Sequence[float] = (0.0, 0.0, 0.0),
    package_dirs: Sequence[str] = (),
    description: str | None = None,
) -> RobotConfig:
    """A :class:`RobotConfig` from flat parameters (as ROS parameters come): ``""`` URDF and no
    ``description`` = the Panda, ``""`` camera parent = ``panda_hand``.

    Raises:
        ValueError: a custom URDF without ``camera_parent``, or bad poses.
    """
    if (urdf_path or description) and not camera_parent:
        raise ValueError("camera_parent: required with a custom URDF (the link that carries the camera)")
    return RobotConfig(
        urdf_path=urdf_path or None,
        package_dirs=tuple(package_dirs),
        description=description,
        world_from_base=pose_from_xyz_rpy(base_xyz, base_rpy),
        camera_parent=camera_parent or "panda_hand",
        parent_from_camera=pose_from_xyz_rpy(camera_xyz, camera_rpy),
    )


class RobotModel:
    """Kinematic and collision model of an arm with a camera (pinocchio + coal).

    Attributes:
        model, collision_model, visual_model: the pinocchio models, with the base pose folded
            into the joints attached to the root and a ``camera_optical`` operational frame.
        joint_names: names of the configuration entries (1-DoF joints, pinocchio order).
        lower, upper: joint limits ``(nq,)``.
        chain: indices into ``q`` of the joints that move the camera (the IK variables).
        reference_q: the reference configuration ``(nq,)``.
        camera_frame: pinocchio frame id of the optical frame.

    Raises:
        ValueError: unreadable or invalid URDF, unsupported joints, unknown camera link, bad poses
            or a reference naming unknown joints.
    """

    CAMERA_FRAME = "camera_optical"

    def __init__(self, config: RobotConfig | None = None) -> None:
        import pinocchio as pin

        self.config = config or RobotConfig()
        if self.config.urdf_path is None and self.config.description is None:
            urdf, meshes = panda_urdf()
            package_dirs = [str(meshes.parent), *self.config.package_dirs]
        else:
            urdf = self.config.urdf_file()
            package_dirs = list(self.config.package_dirs)
            if not urdf.is_file():
                raise ValueError(f"robot: URDF file {str(urdf)!r} does not exist")
        world_from_base = check_pose(self.config.world_from_base, "world_from_base")
        parent_from_camera = check_pose(self.config.parent_from_camera, "parent_from_camera")
        try:
            model, collision, visual = pin.buildModelsFromUrdf(str(urdf), package_dirs=package_dirs)
        except Exception as error:  # pinocchio raises ValueError/RuntimeError with parser details
            raise ValueError(f"robot: cannot load URDF {str(urdf)!r}: {error}") from error
        if model.nq == 0:
            raise ValueError(f"robot: URDF {str(urdf)!r} has no movable joints")
        for index in range(1, model.njoints):
            joint = model.joints[index]
            if joint.nq != 1 or joint.nv != 1:
                raise ValueError(
                    f"robot: joint {model.names[index]!r} of type {joint.shortname()} is not supported "
                    "(only revolute and prismatic joints with limits)"
                )
        _place_root(pin, model, (collision, visual), world_from_base)
        if not model.existFrame(self.config.camera_parent):
            links = [f.name for f in model.frames if f.type == pin.FrameType.BODY]
            raise ValueError(
                f"robot: camera_parent {self.config.camera_parent!r} is not a link of the URDF; links: {links}"
            )
        parent = model.frames[model.getFrameId(self.config.camera_parent)]
        placement = parent.placement * pin.SE3(parent_from_camera[:3, :3], parent_from_camera[:3, 3])
        name = self.CAMERA_FRAME if not model.existFrame(self.CAMERA_FRAME) else f"nbv_{self.CAMERA_FRAME}"
        self.camera_frame = model.addFrame(pin.Frame(name, parent.parentJoint, placement, pin.FrameType.OP_FRAME))
        self.model, self.collision_model, self.visual_model = model, collision, visual
        self.data = model.createData()
        self.joint_names: list[str] = [model.names[i] for i in range(1, model.njoints)]
        self.lower = np.array(model.lowerPositionLimit, dtype=np.float64)
        self.upper = np.array(model.upperPositionLimit, dtype=np.float64)
        if not (np.all(np.isfinite(self.lower)) and np.all(np.isfinite(self.upper))) or np.any(self.lower > self.upper):
            raise ValueError("robot: every joint needs finite limits with lower <= upper")
        chain_joints = []
        joint = parent.parentJoint
        while joint > 0:
            chain_joints.append(joint)
            joint = model.parents[joint]
        if not chain_joints:
            raise ValueError(f"robot: camera_parent {self.config.camera_parent!r} does not move with any joint")
        self.chain = np.array(sorted(model.idx_qs[j] for j in chain_joints), dtype=np.int64)
        reference = self.config.reference
        if reference is None:  # the Panda's ready pose for any description of the Panda (joint names)
            reference = PANDA_READY if set(PANDA_READY) <= set(self.joint_names) else {}
        unknown = sorted(set(reference) - set(self.joint_names))
        if unknown:
            raise ValueError(f"robot: reference names unknown joints {unknown}; joints: {self.joint_names}")
        middle = (self.lower + self.upper) / 2.0
        self.reference_q = np.clip(self.configuration(reference, base=middle), self.lower, self.upper)

    @property
    def nq(self) -> int:
        return int(self.model.nq)

    def configuration(self, joint_positions: Mapping[str, float], base: np.ndarray | None = None) -> np.ndarray:
        """The configuration vector of named joint positions (e.g. a ``JointState``).

        Joints missing from the mapping keep their value in ``base`` (default: the reference).

        Raises:
            ValueError: unknown joint names (the message lists the model's joints) or
                non-finite positions.
        """
        unknown = sorted(set(joint_positions) - set(self.joint_names))
        if unknown:
            raise ValueError(f"joint_states: unknown joint names {unknown}; the robot's joints are {self.joint_names}")
        q = np.array(self.reference_q if base is None else base, dtype=np.float64).reshape(self.nq)
        for name, value in joint_positions.items():
            if not math.isfinite(float(value)):
                raise ValueError(f"joint_states: joint {name!r} has a non-finite position {value}")
            q[self.joint_names.index(name)] = float(value)
        return q

    def joint_state_configuration(self, names: Sequence[str], positions: Sequence[float]) -> np.ndarray:
        """The configuration of a complete joint state (``sensor_msgs/JointState`` names and
        positions): every joint of the robot must be named, once.

        Raises:
            ValueError: names and positions of different lengths, duplicate, unknown or missing
                joint names (the message names them), or non-finite positions.
        """
        names = checked_joint_names(names, positions)
        missing = [name for name in self.joint_names if name not in names]
        unknown = sorted(set(names) - set(self.joint_names))
        if missing or unknown:
            raise ValueError(
                f"joint_states: unknown joint names {unknown}, missing joints {missing}; "
                f"the robot's joints are {self.joint_names}"
            )
        return self.configuration(dict(zip(names, positions, strict=True)))

    def joint_positions(self, q: np.ndarray) -> dict[str, float]:
        """Name → position of a configuration vector."""
        q = self.check_q(q)
        return {name: float(value) for name, value in zip(self.joint_names, q, strict=True)}

    def check_q(self, q: np.ndarray, name: str = "q") -> np.ndarray:
        """Validate one configuration vector ``(nq,)``; return it as float64.

        Raises:
            ValueError: wrong length or non-finite values.
        """
        arr = np.asarray(q, dtype=np.float64)
        if arr.shape != (self.nq,):
            raise ValueError(f"{name}: expected {self.nq} joint positions {self.joint_names}, got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name}: contains NaN or infinite values")
        return arr

    def within_limits(self, q: np.ndarray, tol: float = 1e-9) -> bool:
        q = self.check_q(q)
        return bool(np.all(q >= self.lower - tol) and np.all(q <= self.upper + tol))

    def camera_pose(self, q: np.ndarray) -> np.ndarray:
        """``world_from_optical`` 4×4 of a configuration (pinocchio forward kinematics)."""
        import pinocchio as pin

        q = self.check_q(q)
        pin.forwardKinematics(self.model, self.data, q)
        return pin.updateFramePlacement(self.model, self.data, self.camera_frame).homogeneous.copy()

    def frame_pose(self, q: np.ndarray, frame: str) -> np.ndarray:
        """World pose of any pinocchio frame (link) at a configuration.

        Raises:
            ValueError: unknown frame name.
        """
        import pinocchio as pin

        if not self.model.existFrame(frame):
            raise ValueError(f"frame: {frame!r} is not a frame of the robot")
        q = self.check_q(q)
        pin.forwardKinematics(self.model, self.data, q)
        return pin.updateFramePlacement(self.model, self.data, self.model.getFrameId(frame)).homogeneous.copy()


def _place_root(pin, model, geometry_models, world_from_base: np.ndarray) -> None:
    """Fold the base pose into everything attached to the root (joints, frames, geometry)."""
    base = pin.SE3(world_from_base[:3, :3], world_from_base[:3, 3])
    for index in range(1, model.njoints):
        if model.parents[index] == 0:
            model.jointPlacements[index] = base * model.jointPlacements[index]
    for index, frame in enumerate(model.frames):
        if frame.parentJoint == 0 and index > 0:
            frame.placement = base * frame.placement
            model.frames[index] = frame
    for geometry_model in geometry_models:
        for index, obj in enumerate(geometry_model.geometryObjects):
            if obj.parentJoint == 0:
                obj.placement = base * obj.placement
                geometry_model.geometryObjects[index] = obj
