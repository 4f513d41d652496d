#!/usr/bin/env python3
"""Start our nodes beside an existing robot graph, in one command (there is no ``ros2 launch`` here).

    your robot: robot_state_publisher (/robot_description, /tf), joint_state_broadcaster(s)
                (/joint_states), a joint_trajectory_controller (FollowJointTrajectory), a depth
                camera driver (16UC1 depth + CameraInfo in its optical frame)
    ours:       integrator -> /nbv/grid; nbv_planner (/nbv/plan, /nbv/explore) <->
                completion_server, gain_server (/nbv/evaluate_views); on request (--nodes) the
                octomap_bridge (/nbv/grid -> OctoMap, MoveIt's /planning_scene)

Every node gets the same ``--params-file`` (a ROS 2 parameters YAML: a ``/**`` block for what they
share, one block per node; examples for a UR5e-like and a Panda-like arm with a D435-like camera in
``nbv_prob_cnn/ros/config/``), and the same ``--remap`` rules (e.g. the camera driver's topic names
onto ``/camera/depth/image`` and ``/camera/depth/camera_info``). The nodes join the ROS domain of
this shell (``ROS_DOMAIN_ID``, discovery as configured): the robot's, not a private one.

With ``--views N`` an ``Explore`` goal of N views is sent once the graph is up (the CSV, PNG and
``graph.json`` go to ``--out``); without it the nodes serve until Ctrl-C. Ctrl-C stops every
process (no orphans). When a node exits (a bad parameter, no ``/robot_description`` within its
wait), the launcher prints its last error line and its log, and stops the rest. Logs: one file per
node in ``<out>/logs/``.

Exit status: 0 explored, 1 the exploration failed, 2 a bad argument, 4 a node exited,
124 ``--timeout`` passed (with ``--views``), 130 Ctrl-C.

Example:
    python launch_scripts/robot.py --params-file nbv_prob_cnn/ros/config/ur5e_d435.yaml \\
        --remap /camera/depth/image:=/camera/camera/depth/image_rect_raw \\
        --remap /camera/depth/camera_info:=/camera/camera/depth/camera_info --views 10
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from nbv_prob_cnn.planners.registry import ros_method_names
from nbv_prob_cnn.ros.graph import NodeGraph, run_graph

#: Our nodes, started in this order (the servers before the planner that calls them).
NODES = ("integrator", "completion_server", "gain_server", "nbv_planner")
#: Nodes started only when ``--nodes`` names them.
OPTIONAL_NODES = ("octomap_bridge",)


def node_command(node: str, params_file: Path | None, remaps: list[str], namespace: str) -> list[str]:
    """The command line of one of our nodes with the shared parameters file and remappings."""
    cmd = [sys.executable, "-m", f"nbv_prob_cnn.ros.{node}", "--ros-args"]
    if namespace:
        cmd += ["-r", f"__ns:={namespace}"]
    if params_file is not None:
        cmd += ["--params-file", str(params_file)]
    for rule in remaps:
        cmd += ["-r", rule]
    return cmd


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--params-file", type=Path, help="ROS 2 parameters YAML for every node")
    parser.add_argument("--remap", action="append", default=[], metavar="FROM:=TO", help="remapping for every node")
    parser.add_argument("--namespace", default="", help="namespace of our nodes (e.g. /nbv1)")
    parser.add_argument(
        "--nodes", nargs="+", default=list(NODES), choices=NODES + OPTIONAL_NODES,
        help="which of our nodes to start (default: " + " ".join(NODES) + ")",
    )  # fmt: skip
    parser.add_argument("--views", type=int, default=0, help="send an Explore goal of this many views (0: serve only)")
    methods = ros_method_names()
    parser.add_argument(
        "--method", default="", choices=["", *methods], metavar="METHOD",
        help="the Explore goal's method (default: the planner's parameter): " + ", ".join(methods),
    )  # fmt: skip
    parser.add_argument("--out", type=Path, default=Path("out/robot"), help="logs and exploration outputs")
    parser.add_argument(
        "--timeout", type=float, default=3600.0,
        help="with --views: seconds for the whole run, the start of the graph included (default 3600; then "
        "exit status 124); without, the nodes serve until Ctrl-C",
    )  # fmt: skip
    return parser.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.params_file is not None and not args.params_file.is_file():
        raise SystemExit(f"--params-file: no such file {args.params_file}")
    for rule in args.remap:
        if ":=" not in rule:
            raise SystemExit(f"--remap: expected FROM:=TO, got {rule!r}")
    env = dict(os.environ, PYTHONUNBUFFERED="1")  # the robot's domain and discovery settings, as they are

    def start_nodes(graph: NodeGraph) -> None:
        for node in args.nodes:
            graph.start(node, node_command(node, args.params_file, args.remap, args.namespace))

    env["ROS_DOMAIN_ID"] = env.get("ROS_DOMAIN_ID") or "0"  # unset or empty: the default domain, named
    if args.views <= 0:
        print(f"[robot] starting {', '.join(args.nodes)}; Ctrl-C stops them", flush=True)
        return run_graph(start_nodes, None, env, args.out / "logs", "robot")
    if args.namespace:
        raise SystemExit("--views with --namespace: the Explore client runs without a namespace; send the goal "
                         "to <namespace>/nbv/explore yourself")  # fmt: skip
    client = [sys.executable, "-m", "nbv_prob_cnn.ros.explore_client", "--views", str(args.views),
              "--method", args.method, "--out", str(args.out), "--title", "your robot",
              "--timeout", str(args.timeout), "--ready-timeout", "300"]  # fmt: skip
    return run_graph(start_nodes, client, env, args.out / "logs", "robot", timeout_s=args.timeout)


if __name__ == "__main__":
    raise SystemExit(main())
