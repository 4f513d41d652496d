"""``nbv node NAME``: run one of our ROS 2 nodes (as ``ros2 run nbv_prob_cnn NAME`` would)."""

from __future__ import annotations

import argparse
import importlib
import sys

NAME = "node"
HELP = (
    "Run a ROS 2 node of this package, e.g. `nbv node nbv_planner --ros-args -p method:=cnn_prob`; "
    "`nbv node NAME --help` lists its topics, services and parameters (descriptions, ranges, defaults) without "
    "starting it."
)


def available_nodes() -> list[str]:
    from nbv_prob_cnn.ros import NODES

    return sorted(NODES)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", help="node name (module under nbv_prob_cnn.ros)")
    parser.add_argument("ros_args", nargs=argparse.REMAINDER, help="arguments passed to the node (--ros-args ...)")


def run(args: argparse.Namespace) -> int:
    nodes = available_nodes()
    if args.name not in nodes:
        raise ValueError(f"unknown node {args.name!r}; available: {', '.join(nodes)}")
    if args.ros_args and args.ros_args[0] in ("-h", "--help"):
        from nbv_prob_cnn.ros.node_docs import help_text

        print(help_text(args.name))
        return 0
    module = importlib.import_module(f"nbv_prob_cnn.ros.{args.name}")
    return int(module.main([sys.argv[0], *args.ros_args]) or 0)
