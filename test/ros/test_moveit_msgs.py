"""The moveit_msgs and object_recognition_msgs copies in msg_defs/ are wire-compatible with MoveIt 2:
the type hashes of the built interfaces equal those of a build of the real moveit_msgs, and an
independent RIHS01 computation (rosbags, from the definitions in msg_defs/) agrees.

Where the expected values come from: the generated ``move_group__description.c`` of a colcon build
of moveit_msgs from source published on GitHub (orka375/moveit2,
``build/moveit_msgs/rosidl_generator_c/moveit_msgs/action/detail/move_group__description.c``: the
hashes of MoveGroup's types and the expected hash of every type they hold). Its hashes of the
standard packages (geometry_msgs, sensor_msgs, std_msgs, ...) equal those of the Jazzy wheels here,
so it was built against Jazzy's interfaces; its moveit_msgs version is not stated there. The hashes
of the Jazzy binary release (ros-jazzy-moveit-msgs) were not available offline to compare with: a
moveit_msgs release whose definitions differ from the ones that build used would show here only
once someone pins those hashes from a Jazzy system (``ros2 topic info -v`` on move_group's topics).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

MSG_DEFS = Path(__file__).resolve().parents[2] / "msg_defs"

#: The hashes of that build (see the module docstring): MoveGroup's types, PlanningScene, the error codes.
MOVEIT_HASHES = {
    "moveit_msgs/action/MoveGroup": "RIHS01_8c41d70908a2d26b564ddac31e9710f697a753bbd2a4d229542f76271daefc0b",
    "moveit_msgs/action/MoveGroup_Goal": "RIHS01_c2a80a3f1ae1a97fb8c6e7ff35da28d7dd161f64683474801ed4371e4fd220ce",
    "moveit_msgs/action/MoveGroup_Result": "RIHS01_188b11f0cf9d62360f554ae9a3f55cb9162767be782a7e05ee6a66371f262ebe",
    "moveit_msgs/action/MoveGroup_Feedback": "RIHS01_d0cb5a6d2213e97858a73830b26b1c8f1d8989b6b47c489886527a419452fafe",
    "moveit_msgs/action/MoveGroup_SendGoal": "RIHS01_e2964f7aac611dc92a76e7b3e925a2d9e039d4f70ef348af0dbe36e8f3274527",
    "moveit_msgs/action/MoveGroup_SendGoal_Request":
        "RIHS01_02e8af2a61d8fe3044deddcbdffd536e96c2d822e64338c49397798ea665ac90",
    "moveit_msgs/action/MoveGroup_SendGoal_Response":
        "RIHS01_53b2e441aac2e196a87222d1f9f64c0745f4288d1b967826993d6a35edeceaab",
    "moveit_msgs/action/MoveGroup_SendGoal_Event":
        "RIHS01_03e82de522bf6edabb0d4d3a9fe5a02eee63ca49f939f2e4b29e0efa2026b10c",
    "moveit_msgs/action/MoveGroup_GetResult": "RIHS01_730c808018e9f6d10ae073e3a7e9da365e791fe5a461c6fe269af927437969fa",
    "moveit_msgs/action/MoveGroup_GetResult_Request":
        "RIHS01_3d618f3ef553f48620196cb9586ab1012cc219c597a409bba860f6a23b8743a4",
    "moveit_msgs/action/MoveGroup_GetResult_Response":
        "RIHS01_c13439db4b8be0a7056e604be863d5f4b6265cdb64887e26e12cfa5622c58682",
    "moveit_msgs/action/MoveGroup_GetResult_Event":
        "RIHS01_bcf1f25a2fc5b63930b87e0f017260205c93b58b4be2ca657535a4b4600c4427",
    "moveit_msgs/action/MoveGroup_FeedbackMessage":
        "RIHS01_c5b66e44e3b976db5536bf3eb773d83238c1d1d8c53ccaa7ccba28fad55fa352",
    "moveit_msgs/msg/PlanningScene": "RIHS01_0f58540ad5eab4b9ea827d53b763c793d8cabd202b3b301fcee25afa4ce1bd80",
    "moveit_msgs/msg/PlanningSceneWorld": "RIHS01_e08e6a4a81ca6b6a6953ac758dadc2c949555093efea6a9a22d9accf62c2c099",
    "moveit_msgs/msg/MotionPlanRequest": "RIHS01_f82ed20da5f8f93146999c1a3cfe34b56b97fc10333b40cac69782a1210888d7",
    "moveit_msgs/msg/MoveItErrorCodes": "RIHS01_dcda8a9950cf6dd6ac221c2c0d2509f52f136afa0403dd19beacdf07e83e4a07",
    "object_recognition_msgs/msg/ObjectType": "RIHS01_5eb3ee3976403366d7c50d7dbee8bec96b3bced1e752674a7194a35841632134",
}  # fmt: skip


def _built_hash(type_name: str) -> str:
    """The hash rosidl's type-description generator wrote for the installed interface (an action's
    parts are in the action's file)."""
    import importlib
    import json

    package, kind, name = type_name.split("/")
    # <prefix>/lib/python3.X/site-packages/<package>/__init__.py -> <prefix>/share/<package>
    prefix = Path(importlib.import_module(package).__file__).parents[4]
    with open(prefix / "share" / package / kind / f"{name.split('_')[0]}.json") as f:
        hashes = {entry["type_name"]: entry["hash_string"] for entry in json.load(f)["type_hashes"]}
    return hashes[type_name]


@pytest.mark.parametrize("type_name", sorted(MOVEIT_HASHES))
def test_built_type_hash_is_the_moveit_builds(type_name):
    pytest.importorskip("moveit_msgs.action")
    assert _built_hash(type_name) == MOVEIT_HASHES[type_name]


def _definitions_store():
    """A rosbags Jazzy type store with the definitions of msg_defs/ (moveit_msgs' action parts as
    messages of their own names) registered."""
    typesys = pytest.importorskip("rosbags.typesys")
    store = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    types = {}
    for package in ("octomap_msgs", "object_recognition_msgs", "moveit_msgs"):
        for path in sorted((MSG_DEFS / package / "msg").glob("*.msg")):
            types.update(typesys.get_types_from_msg(path.read_text(), f"{package}/msg/{path.stem}"))
    action = (MSG_DEFS / "moveit_msgs/action/MoveGroup.action").read_text()
    goal, result, feedback = re.split(r"^---$", action, flags=re.M)
    for part, text in (("Goal", goal), ("Result", result), ("Feedback", feedback)):
        text = re.sub(r"^([A-Z]\w*\s)", r"moveit_msgs/\1", text, flags=re.M)  # the package's own messages
        types.update(typesys.get_types_from_msg(text, f"moveit_msgs/action/MoveGroup_{part}"))
    store.register(types)
    return store


@pytest.mark.parametrize(
    "type_name", [name for name in sorted(MOVEIT_HASHES) if "/msg/" in name or name.endswith(("_Goal", "_Result",
                                                                                              "_Feedback"))]
)  # fmt: skip
def test_independent_rihs01_of_the_definitions_agrees(type_name):
    assert _definitions_store().hash_rihs01(type_name) == MOVEIT_HASHES[type_name]
