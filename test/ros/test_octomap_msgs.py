"""The octomap_msgs copy in msg_defs/ is wire-compatible with the real octomap_msgs: the type hashes
of the built interfaces equal those of colcon builds of the real package against Jazzy's
interfaces, and an independent RIHS01 computation (rosbags, from the definitions in msg_defs/) agrees.

Where the expected values come from: rosidl's generated ``*__description.c`` of public colcon builds
found with the search tool, offline: ``octomap_msgs/srv/detail/get_octomap__description.c`` of a
build of octomap_msgs itself (the hashes of GetOctomap, its request, response and event, and the
expected hash of ``Octomap``), and a build of a package whose service holds a
``moveit_msgs/PlanningSceneWorld`` (the expected hashes of ``Octomap`` and ``OctomapWithPose``).
Their hashes of the standard packages (std_msgs/Header, builtin_interfaces/Time, service_msgs) equal
those of the Jazzy wheels here. No build showing ``BoundingBoxQuery``'s hash was found: it is
checked by the independent computation only (which reads our definition, so it cannot tell a
field that differs from the release's).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

MSG_DEFS = Path(__file__).resolve().parents[2] / "msg_defs"

#: The hashes of those builds (see the module docstring).
OCTOMAP_HASHES = {
    "octomap_msgs/msg/Octomap": "RIHS01_9891a19a05b70ec20aa8f45db3f8300b9ab80afff32c61c549d25087da9625b0",
    "octomap_msgs/msg/OctomapWithPose": "RIHS01_e65f8760aa96a2acef86b6d206175cfc78420082b6159dd3fa6ebf93f5f81979",
    "octomap_msgs/srv/GetOctomap": "RIHS01_c43f2ceb835f797f3d2a2c3d9000e4691207d8c7bfb443119b4e90daaabb5d6c",
    "octomap_msgs/srv/GetOctomap_Request": "RIHS01_cd35df88d5efc717a01bcca35289d9bb1ea7099ec081cb9ae6c282c269d7fa59",
    "octomap_msgs/srv/GetOctomap_Response": "RIHS01_874a18c1909a064d2dbf207a8e4de6ccc8d7d3d93edce2ac4d4205f9df0495db",
    "octomap_msgs/srv/GetOctomap_Event": "RIHS01_9347720ba6abc64c1a3d6b360084818c9a10793d288770b8f3aadfc0f788c5b4",
}


def _built_hash(type_name: str) -> str:
    """The hash rosidl's type-description generator wrote for the installed interface (a service's
    parts are in the service's file)."""
    import importlib
    import json

    package, kind, name = type_name.split("/")
    # <prefix>/lib/python3.X/site-packages/<package>/__init__.py -> <prefix>/share/<package>
    prefix = Path(importlib.import_module(package).__file__).parents[4]
    with open(prefix / "share" / package / kind / f"{name.split('_')[0]}.json") as f:
        hashes = {entry["type_name"]: entry["hash_string"] for entry in json.load(f)["type_hashes"]}
    return hashes[type_name]


@pytest.mark.parametrize("type_name", sorted(OCTOMAP_HASHES))
def test_built_type_hash_is_the_real_packages(type_name):
    pytest.importorskip("octomap_msgs.srv")
    assert _built_hash(type_name) == OCTOMAP_HASHES[type_name]


def _definitions_store():
    """A rosbags Jazzy type store with octomap_msgs' messages and service parts from msg_defs/."""
    typesys = pytest.importorskip("rosbags.typesys")
    store = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    types = {}
    for path in sorted((MSG_DEFS / "octomap_msgs" / "msg").glob("*.msg")):
        types.update(typesys.get_types_from_msg(path.read_text(), f"octomap_msgs/msg/{path.stem}"))
    for path in sorted((MSG_DEFS / "octomap_msgs" / "srv").glob("*.srv")):
        request, response = re.split(r"^---$", path.read_text(), flags=re.M)
        for part, text in (("Request", request), ("Response", response)):
            if not re.search(r"^\s*[A-Za-z]", text, flags=re.M):  # an empty part, as rosidl fills it
                text = "uint8 structure_needs_at_least_one_member\n"
            parsed = typesys.get_types_from_msg(text, f"octomap_msgs/srv/{path.stem}_{part}")
            types.update({name.replace("/srv/msg/", "/srv/"): value for name, value in parsed.items()})
    store.register(types)
    return store


@pytest.mark.parametrize(
    "type_name", [n for n in sorted(OCTOMAP_HASHES) if "/msg/" in n or n.endswith(("_Request", "_Response"))]
)
def test_independent_rihs01_of_the_definitions_agrees(type_name):
    assert _definitions_store().hash_rihs01(type_name) == OCTOMAP_HASHES[type_name]


@pytest.mark.parametrize("part", ["Request", "Response"])
def test_bounding_box_query_agrees_with_the_independent_computation(part):
    pytest.importorskip("octomap_msgs.srv")
    type_name = f"octomap_msgs/srv/BoundingBoxQuery_{part}"
    assert _built_hash(type_name) == _definitions_store().hash_rihs01(type_name)
