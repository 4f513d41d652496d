"""Robot descriptions as ROS graphs carry them: URDF or xacro text, ``package://`` resources, and
the camera mount of a robot that the description does not contain.

* :func:`read_description` turns a ``robot_description`` string or a ``.urdf`` / ``.xacro`` file
  into plain URDF text (xacro through the ``xacro`` package, as ``ros2 run xacro xacro`` does).
* :func:`resolve_package_uris` rewrites every ``package://<pkg>/<path>`` to an absolute path, the
  package found in ``package_dirs``, then ``AMENT_PREFIX_PATH`` (``<prefix>/share/<pkg>``), then
  ``ROS_PACKAGE_PATH``; a package found nowhere is an error naming it and where it was looked for.
* :func:`mount_camera` adds a fixed frame (a camera's optical frame) and, optionally, a fixed
  joint from a world link to the root, as a driver's description with the camera in it would have.
* :func:`urdf_links` / :func:`urdf_root_link` read what the description contains.

No ROS here: the nodes pass the text they received on ``/robot_description``.
"""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: ``package://<name>/<rest>`` in a URDF attribute (mesh filenames, textures).
PACKAGE_URI = re.compile(r"package://([^/\"'\s]+)/")


def _package_xml_name(folder: Path) -> str | None:
    """The ``<name>`` of ``folder/package.xml`` (None without one)."""
    manifest = folder / "package.xml"
    if not manifest.is_file():
        return None
    try:
        name = ET.parse(manifest).getroot().findtext("name")
    except ET.ParseError:
        return None
    return name.strip() if name else None


def _candidates(package: str, root: Path) -> list[Path]:
    """Folders under one search root that may be ``package``: the root itself (named so, or its
    package.xml says so) and ``root/package``."""
    found = []
    if root.name == package or _package_xml_name(root) == package:
        found.append(root)
    found.append(root / package)
    return found


def find_package(package: str, package_dirs: Sequence[str] = (), env: Mapping[str, str] | None = None) -> Path:
    """The folder of ROS package ``package``, for ``package://`` and ``$(find)``.

    Searched in order: each of ``package_dirs`` (the package's folder itself or its parent),
    ``<prefix>/share/<package>`` for each prefix of ``AMENT_PREFIX_PATH``, and each entry of
    ``ROS_PACKAGE_PATH`` (the folder itself or its parent).

    Raises:
        ValueError: not found; the message names the package and every place looked at.
    """
    env = os.environ if env is None else env
    roots: list[tuple[str, Path]] = [("package_dirs", Path(p).expanduser()) for p in package_dirs if p]
    looked: list[str] = []
    for source, root in roots:
        for folder in _candidates(package, root):
            if folder.is_dir():
                return folder
        looked.append(f"{source} {root}")
    for prefix in filter(None, env.get("AMENT_PREFIX_PATH", "").split(os.pathsep)):
        folder = Path(prefix) / "share" / package
        if folder.is_dir():
            return folder
        looked.append(f"AMENT_PREFIX_PATH {prefix}/share")
    for entry in filter(None, env.get("ROS_PACKAGE_PATH", "").split(os.pathsep)):
        for folder in _candidates(package, Path(entry)):
            if folder.is_dir():
                return folder
        looked.append(f"ROS_PACKAGE_PATH {entry}")
    where = "; ".join(looked) if looked else "package_dirs, AMENT_PREFIX_PATH and ROS_PACKAGE_PATH are all empty"
    raise ValueError(
        f"robot description: package {package!r} (package://{package}/...) not found ({where}); "
        f"add the folder that contains {package}/ to the package_dirs parameter"
    )


def resolve_package_uris(text: str, package_dirs: Sequence[str] = (), env: Mapping[str, str] | None = None) -> str:
    """``text`` with every ``package://<pkg>/`` replaced by the package's absolute folder.

    Raises:
        ValueError: a package that :func:`find_package` does not find (the first one, named).
    """
    folders: dict[str, str] = {}

    def replace(match: re.Match) -> str:
        package = match.group(1)
        if package not in folders:
            folders[package] = str(find_package(package, package_dirs, env).resolve())
        return folders[package] + "/"

    return PACKAGE_URI.sub(replace, text)


def is_xacro(text: str) -> bool:
    """Whether a description still needs xacro (it uses the xacro namespace)."""
    return "http://www.ros.org/wiki/xacro" in text or "xacro:" in text


def expand_xacro(path: str | None = None, text: str | None = None, mappings: Mapping[str, str] | None = None) -> str:
    """URDF text of a xacro file or string (``xacro`` package; ``mappings`` are its ``name:=value`` args).

    Raises:
        ValueError: xacro reports an error (undefined property, missing include, ...).
    """
    import xacro

    try:
        if path is not None:
            doc = xacro.process_file(path, mappings=dict(mappings or {}))
        else:
            doc = xacro.parse(text)
            xacro.process_doc(doc, mappings=dict(mappings or {}))
    except Exception as error:  # xacro raises XacroException, OSError, ExpatError, NameError ...
        raise ValueError(f"robot description: xacro failed on {path or 'the description text'}: {error}") from error
    return doc.toxml()


def read_description(
    text: str = "",
    path: str = "",
    package_dirs: Sequence[str] = (),
    xacro_args: Mapping[str, str] | None = None,
    env: Mapping[str, str] | None = None,
    resolve: bool = True,
) -> str:
    """Plain URDF text with absolute resource paths (``package://`` kept when not ``resolve``),
    from a description string or a file.

    Args:
        text: a ``robot_description`` (URDF, or xacro when it uses the xacro namespace); wins over ``path``.
        path: a ``.urdf`` file, or a ``.xacro`` / ``.urdf.xacro`` file expanded by xacro.
        package_dirs: extra folders for ``package://`` (see :func:`find_package`).
        xacro_args: ``name → value`` arguments of the xacro file.

    Raises:
        ValueError: neither given, an unreadable file, a xacro error, no ``<robot>`` root, or a
            missing package.
    """
    if text:
        urdf = expand_xacro(text=text, mappings=xacro_args) if is_xacro(text) else text
        source = "the robot_description text"
    elif path:
        file = Path(path).expanduser()
        if not file.is_file():
            raise ValueError(f"robot description: URDF file {str(file)!r} does not exist")
        urdf = expand_xacro(path=str(file), mappings=xacro_args) if file.name.endswith(".xacro") else file.read_text()
        source = str(file)
    else:
        raise ValueError("robot description: empty (no robot_description text and no urdf_path)")
    try:
        root = ET.fromstring(urdf)
    except ET.ParseError as error:
        raise ValueError(f"robot description: {source} is not valid XML: {error}") from error
    if root.tag != "robot":
        raise ValueError(f"robot description: {source} has root <{root.tag}>, expected <robot>")
    return resolve_package_uris(urdf, package_dirs, env) if resolve else urdf


@dataclass(frozen=True)
class UrdfJoint:
    """One ``<joint>`` of a URDF: its links and whether it is fixed (``/tf_static``) or moves (``/tf``)."""

    name: str
    parent: str
    child: str
    fixed: bool


def urdf_joints(text: str) -> list[UrdfJoint]:
    """The joints of a URDF, in document order."""
    joints = []
    for joint in ET.fromstring(text).findall("joint"):
        parent, child = joint.find("parent"), joint.find("child")
        if parent is None or child is None:
            raise ValueError(f"robot description: joint {joint.get('name')!r} lacks <parent> or <child>")
        joints.append(UrdfJoint(joint.get("name", ""), parent.get("link", ""), child.get("link", ""),
                                joint.get("type") == "fixed"))  # fmt: skip
    return joints


def urdf_links(text: str) -> list[str]:
    """Names of the ``<link>`` elements of a URDF."""
    return [link.get("name", "") for link in ET.fromstring(text).findall("link")]


def urdf_root_link(text: str) -> str:
    """The link that is no joint's child.

    Raises:
        ValueError: none or several such links (not a tree).
    """
    children = {joint.child for joint in urdf_joints(text)}
    roots = [name for name in urdf_links(text) if name not in children]
    if len(roots) != 1:
        raise ValueError(f"robot description: expected one root link, found {roots}")
    return roots[0]


def _origin(pose: np.ndarray) -> dict[str, str]:
    """URDF ``<origin>`` attributes of a 4×4 pose (rpy as ``Rz(yaw) Ry(pitch) Rx(roll)``)."""
    from scipy.spatial.transform import Rotation

    yaw, pitch, roll = Rotation.from_matrix(pose[:3, :3]).as_euler("ZYX")
    return {
        "xyz": " ".join(repr(float(v)) for v in pose[:3, 3]),
        "rpy": " ".join(repr(float(v)) for v in (roll, pitch, yaw)),
    }


def add_fixed_link(text: str, parent: str, child: str, parent_from_child: np.ndarray, joint: str = "") -> str:
    """``text`` with a fixed joint ``parent → child``, one of them a new link: a frame fixed on an
    existing link, or a new root above the old one.

    Raises:
        ValueError: both links exist already, or neither does.
    """
    root = ET.fromstring(text)
    links = urdf_links(text)
    if (parent in links) == (child in links):
        state = "both exist" if parent in links else "neither exists"
        raise ValueError(f"robot description: cannot fix {child!r} on {parent!r}: {state} (links {links})")
    ET.SubElement(root, "link", name=child if parent in links else parent)
    element = ET.SubElement(root, "joint", name=joint or f"{parent}_to_{child}", type="fixed")
    ET.SubElement(element, "parent", link=parent)
    ET.SubElement(element, "child", link=child)
    ET.SubElement(element, "origin", _origin(np.asarray(parent_from_child, dtype=np.float64)))
    return ET.tostring(root, encoding="unicode")


def _origin_pose(element) -> np.ndarray:
    """4×4 pose of a URDF ``<origin>`` element (identity when absent)."""
    from nbv_prob_cnn.arm.robot import pose_from_xyz_rpy

    if element is None:
        return np.eye(4)
    xyz = [float(v) for v in element.get("xyz", "0 0 0").split()]
    rpy = [float(v) for v in element.get("rpy", "0 0 0").split()]
    return pose_from_xyz_rpy(xyz, rpy)


def place_root(text: str, world_frame: str, world_from_base: np.ndarray) -> str:
    """A description standing in ``world_frame`` at ``world_from_base``: a new root link
    ``world_frame`` fixed above the old root, or, when the root already is ``world_frame``, its
    fixed joints moved by ``world_from_base`` (the robot's base placed in that frame).

    Raises:
        ValueError: ``world_frame`` is a link but not the root.
    """
    if world_frame not in urdf_links(text):
        return add_fixed_link(text, world_frame, urdf_root_link(text), world_from_base, f"{world_frame}_joint")
    if urdf_root_link(text) != world_frame:
        raise ValueError(f"robot description: link {world_frame!r} exists but is not the root")
    root = ET.fromstring(text)
    for joint in root.findall("joint"):
        parent = joint.find("parent")
        if parent is not None and parent.get("link") == world_frame:
            origin = joint.find("origin")
            pose = np.asarray(world_from_base, dtype=np.float64) @ _origin_pose(origin)
            if origin is None:
                origin = ET.SubElement(joint, "origin")
            origin.attrib.update(_origin(pose))
    return ET.tostring(root, encoding="unicode")


def mount_camera(
    text: str,
    camera_parent: str,
    parent_from_camera: np.ndarray,
    camera_frame: str,
    world_frame: str = "",
    world_from_base: np.ndarray | None = None,
) -> str:
    """A description with the camera's optical frame fixed on ``camera_parent`` and, with
    ``world_frame``, the robot placed in that frame (:func:`place_root`): what a driver publishes
    for a robot with a camera on its hand (``robot_state_publisher`` puts both on ``/tf_static``).

    Raises:
        ValueError: ``camera_parent`` is not a link, or ``camera_frame`` exists already.
    """
    if camera_parent not in urdf_links(text):
        raise ValueError(f"robot description: camera_parent {camera_parent!r} is not a link; links {urdf_links(text)}")
    if world_frame:
        text = place_root(text, world_frame, np.eye(4) if world_from_base is None else world_from_base)
    return add_fixed_link(text, camera_parent, camera_frame, parent_from_camera, f"{camera_frame}_joint")


__all__ = [
    "add_fixed_link",
    "expand_xacro",
    "find_package",
    "is_xacro",
    "mount_camera",
    "place_root",
    "read_description",
    "resolve_package_uris",
    "UrdfJoint",
    "urdf_joints",
    "urdf_links",
    "urdf_root_link",
]
