"""The tf2_msgs copy in msg_defs/ is wire-compatible with the ROS 2 Jazzy release: the type hashes
of the built interfaces equal the ones a Jazzy system publishes, and an independent RIHS01
computation (rosbags, from its own copy of the Jazzy definitions) agrees."""

import pytest

#: ``ros2 topic info -v /tf`` on a ROS 2 Jazzy system, and tf2_msgs' golden hash (rmw_zenoh's
#: cdr_topic_info tests, ros2 bag metadata of Jazzy bags): the release's hashes.
JAZZY_HASHES = {
    "tf2_msgs/msg/TFMessage": "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "tf2_msgs/msg/TF2Error": "RIHS01_db2485e7d6a0ec75bf087e058ee45df682acc3a621ca7780503d10aac141809a",
}


def _built_hash(type_name: str) -> str:
    """The hash rosidl's type-description generator wrote for the installed interface."""
    import importlib
    import json
    from pathlib import Path

    package, kind, name = type_name.split("/")
    # <prefix>/lib/python3.X/site-packages/<package>/__init__.py -> <prefix>/share/<package>
    prefix = Path(importlib.import_module(package).__file__).parents[4]
    with open(prefix / "share" / package / kind / f"{name}.json") as f:
        hashes = {entry["type_name"]: entry["hash_string"] for entry in json.load(f)["type_hashes"]}
    return hashes[type_name]


@pytest.mark.parametrize("type_name", sorted(JAZZY_HASHES))
def test_built_type_hash_is_the_jazzy_release(type_name):
    pytest.importorskip("tf2_msgs.msg")
    assert _built_hash(type_name) == JAZZY_HASHES[type_name]


@pytest.mark.parametrize("type_name", sorted(JAZZY_HASHES))
def test_independent_rihs01_of_the_jazzy_definition_agrees(type_name):
    typesys = pytest.importorskip("rosbags.typesys")
    store = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    assert store.hash_rihs01(type_name) == JAZZY_HASHES[type_name]


def test_a_tf_publisher_announces_the_jazzy_hash(ros_domain):
    """The hash the middleware puts on the wire for a /tf publisher (what a Jazzy subscriber
    matches against)."""
    pytest.importorskip("tf2_msgs.msg")
    import os
    import time

    import rclpy
    from rclpy.context import Context
    from tf2_msgs.msg import TFMessage

    ros_domain(105 + os.getpid() % 4)  # 105..108: no other test uses these
    context = Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node("tf2_msgs_hash_probe", context=context)
        node.create_publisher(TFMessage, "/tf", 10)
        deadline = time.monotonic() + 10.0
        infos = []
        while not infos and time.monotonic() < deadline:
            infos = node.get_publishers_info_by_topic("/tf")
            time.sleep(0.05)
        assert infos, "the /tf publisher never showed in the graph"
        assert str(infos[0].topic_type_hash) == JAZZY_HASHES["tf2_msgs/msg/TFMessage"]
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
