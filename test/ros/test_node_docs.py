"""docs/nodes.md is generated from the nodes' code and must not go stale; the interfaces it lists
are what a running node really offers."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from nbv_prob_cnn.ros import NODES
from nbv_prob_cnn.ros.node_docs import interfaces, nodes_markdown, parameters

REPO = Path(__file__).resolve().parents[2]


def test_docs_nodes_md_is_up_to_date():
    page = REPO / "docs" / "nodes.md"
    assert page.read_text() == nodes_markdown(), "docs/nodes.md is stale: run `nbv docs nodes --out docs/nodes.md`"


def test_every_node_has_parameters_with_descriptions():
    for name in NODES:
        rows = parameters(name)
        assert rows, name
        assert all(row.description for row in rows), name


@pytest.mark.slow  # starts one node (~10 s)
def test_listed_interfaces_are_what_the_running_integrator_offers(ros_domain, tmp_path):
    import rclpy
    from rclpy.node import Node

    from nbv_prob_cnn.ros.graph import NodeGraph
    from nbv_prob_cnn.ros.stream_node import STREAMS_SUFFIX

    env = ros_domain(200 + os.getpid() % 10)
    defaults = {row.name: row.default for row in parameters("integrator")}

    def active(condition: str) -> bool | None:
        """Whether an interface's condition holds with the default parameters (None: not decidable)."""
        try:
            return bool(eval(condition, {}, dict(defaults))) if condition else True  # noqa: S307
        except Exception:
            return None

    every = interfaces("integrator")
    undecidable = {i.name for i in every if active(i.condition) is None}
    listed = [i for i in every if active(i.condition)]
    expected = {
        "publishes": {i.name for i in listed if i.kind == "topic" and i.direction == "publishes"},
        "subscribes": {i.name for i in listed if i.kind == "topic" and i.direction == "subscribes"},
        "serves": {i.name for i in listed if i.kind == "service" and i.direction == "serves"},
    }
    assert "/nbv/grid" in expected["publishes"] and "/integrator/save" in expected["serves"]
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(env["ROS_DOMAIN_ID"]))
    probe = Node("node_docs_probe", context=context)
    try:
        with NodeGraph(env, log_dir=tmp_path) as graph:  # its log stays for a failure to show
            graph.start_node("integrator", "integrator")
            found: dict[str, set[str]] = {}
            # until it is discovered with every listed interface (it imports open3d first: over a
            # minute when the machine runs a full suite and a hunt beside it, fresh run 12)
            deadline = time.monotonic() + 180.0
            while time.monotonic() < deadline and all(graph.alive().values()):
                try:
                    # the node and its side node for /tf (nbv_prob_cnn.ros.stream_node)
                    found = {
                        kind: {n for node in ("integrator", "integrator" + STREAMS_SUFFIX) for n, _ in query(node, "/")}
                        for kind, query in (
                            ("publishes", probe.get_publisher_names_and_types_by_node),
                            ("subscribes", probe.get_subscriber_names_and_types_by_node),
                            ("serves", probe.get_service_names_and_types_by_node),
                        )
                    }
                except Exception:  # the node is not discovered yet
                    found = {}
                if found and all(expected[k] <= found[k] for k in expected):
                    break
                time.sleep(0.2)
            alive = graph.alive()
    finally:
        probe.destroy_node()
        rclpy.shutdown(context=context)
    assert found, f"the integrator was not discovered (alive: {alive})"
    automatic_topics = {"/rosout", "/parameter_events"}
    automatic_services = ("describe_parameters", "get_parameters", "list_parameters", "set_parameters",
                          "get_parameter_types", "set_parameters_atomically", "get_type_description")  # fmt: skip
    for kind in expected:
        ours = {n for n in found[kind] if n not in automatic_topics and n.rsplit("/", 1)[-1] not in automatic_services}
        ours -= undecidable
        assert ours == expected[kind], (kind, ours ^ expected[kind])
