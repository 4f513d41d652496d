#!/usr/bin/env python3
"""Start the simulated node graph and explore a scene through the Explore action.

    robot side (stand-ins for real drivers)          our nodes
    arm_sim  --/robot_description, /joint_states (arm | gripper), /tf, /tf_static-->  integrator,
             <--/arm_controller/follow_joint_trajectory (control_msgs)----------   nbv_planner, gain_server
    sim_camera --/camera/depth/image (16UC1) + camera_info (optical frame)----->   integrator -> /nbv/grid
                                   nbv_planner <-> completion_server, gain_server <- explore_client (Explore goal)

By default the camera rides on the simulated arm and the robot side talks to our nodes through
the standard interfaces only, as a real arm (robot_state_publisher, joint_state_broadcaster, a
joint_trajectory_controller) and a depth camera driver would: ``arm_sim`` publishes the robot
description with the camera mounted in it, the joint states (the gripper's in its own message),
TF, and serves FollowJointTrajectory; ``sim_camera`` publishes 16UC1 depth + CameraInfo in the
optical frame, taking its own pose from TF. ``nbv_planner`` plans views the arm reaches
collision-free (``use_arm``, the robot read from ``/robot_description``) and sends the timed joint
path to the controller (``move_mode:=trajectory``). ``--move-mode arm`` uses our own
``arm_sim/move_to_joints`` service instead; ``--no-arm`` runs the free-flying camera (teleported by
``sim_camera/move_to``).

Every process gets localhost discovery, its own ROS_DOMAIN_ID and the Fast DDS shared-memory
profile. Ctrl-C cancels the exploration and stops every process (no orphans), then removes the
shared-memory files the graph left behind. When a node exits, the launcher prints its last error
line and its log and stops the rest. Outputs: <out>/views.csv (with each view's surface coverage
of the world), <out>/explored.png,
<out>/grid.npz and one log per node in <out>/logs/.

Exit status: 0 explored, 1 the exploration failed, 2 a bad argument, 4 a node exited,
124 ``--timeout`` passed, 130 Ctrl-C.

Example:  .venv/bin/python launch_scripts/explore_sim.py --views 10 --method cnn_surface [--no-arm]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from nbv_prob_cnn.basics.camera import dataset_defaults
from nbv_prob_cnn.planners.registry import DEFAULT_METHOD, ros_method_names
from nbv_prob_cnn.ros.graph import NodeGraph, ros_environment, run_graph
from nbv_prob_cnn.sensing.sensor_noise import PRESETS

#: Arm parameters of sim_camera and integrator in the arm graph: the camera rides on the arm and
#: sees it, the integrator removes it from the depth before integration.
SIM_CAMERA_WITH_ARM = {"follow_arm": True, "render_arm": True, "encoding": "16UC1"}
INTEGRATOR_WITH_ARM = {"self_filter": True}
#: The simulated scene is static: of the frames the camera streams while it stands still (the arm
#: waits for the next view) the integrator fuses the first few and skips the rest (counted), which
#: leaves the CPU to the planner: 1 with exact depth (a second exact frame from the same pose
#: changes no cell), 3 with a noise preset (repeated noisy frames average the noise out).
STILL_FRAMES_FUSED = {"exact": 1, "noisy": 3}
#: The arm's start: the Panda's camera 0.90 m above the floor at x = 0.25 m, y = 0.742 m, looking at
#: the table centre (0.74, 0.742, 0) (solved with ``arm.ik.solve_camera_pose`` from the ready pose).
#: From the ready pose the camera looks straight down from 0.54 m and sees too little empty space
#: for the arm to move into (every candidate view puts links into unknown cells).
#: Views lower than this (m) are left out with the arm: the CNN's best views lie 2-10 cm above the
#: table top (at 6-8 cm), where the hand around the camera touches the table or unknown space, and
#: checking them spends the planner's check budget before a view the arm can take comes up.
ARM_MIN_VIEW_HEIGHT_M = 0.2
LOOK_OVER_TABLE = [-0.514, -0.296, 0.444, -1.001, 0.161, 1.239, 2.393, 0.04, 0.04]


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", default="3dt", choices=["3du", "3dt"], help="scene type (default 3dt)")
    parser.add_argument("--seed", type=int, default=1000, help="scene seed (default 1000, a held-out scene)")
    parser.add_argument("--views", type=int, default=10, help="views to plan (default 10)")
    methods = ros_method_names()
    parser.add_argument(
        "--method", default=DEFAULT_METHOD, choices=methods, metavar="METHOD",
        help=f"the planner's method (default {DEFAULT_METHOD}): " + ", ".join(methods),
    )  # fmt: skip
    parser.add_argument("--in-process", action="store_true", help="planner completes and ray-casts itself")
    parser.add_argument("--no-arm", action="store_true", help="free-flying camera (no arm_sim, no reachability)")
    parser.add_argument(
        "--move-mode", default="trajectory", choices=["trajectory", "arm"],
        help="arm: FollowJointTrajectory (trajectory, default) or arm_sim/move_to_joints (arm)",
    )  # fmt: skip
    parser.add_argument("--motion-weight", type=float, default=0.0, help="λ of gain − λ·joint path (arm only)")
    parser.add_argument(
        "--free-above", type=float, default=0.25,
        help="tabletop prior (arm): unknown cells at or above this height (m) do not block the arm; < 0 = all block "
        "(default 0.25, nbv_planner's default; it takes 10 views on seed 1000 since the planner counts the space "
        "the arm swept as free)",
    )  # fmt: skip
    parser.add_argument(
        "--initial-joints", type=float, nargs="+", default=LOOK_OVER_TABLE,
        help="arm start configuration, URDF joint order (default: the camera looking over the table; 0 = ready pose)",
    )  # fmt: skip
    parser.add_argument(
        "--noise", default="", choices=["", *PRESETS],
        help="sim_camera's depth-sensor preset (nbv_prob_cnn.sensing.sensor_noise; default: exact depth)",
    )  # fmt: skip
    parser.add_argument("--stop-unknown", type=float, default=0.0, help="stop at this unknown fraction")
    parser.add_argument("--out", default="out/explore_sim", help="output directory")
    parser.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID (default: derived from the pid)")
    parser.add_argument(
        "--timeout", type=float, default=1800.0,
        help="seconds for the whole run, the start of the graph included (default 1800; then exit status 124)",
    )  # fmt: skip
    return parser.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    out = Path(args.out)
    defaults = dataset_defaults(args.dataset)
    common = {"dataset": args.dataset}

    arm = not args.no_arm
    if arm and args.dataset != "3dt":
        raise SystemExit("the arm stands beside the 3DT table: use --dataset 3dt or --no-arm")

    def start_nodes(graph: NodeGraph) -> None:
        if arm:
            graph.start_node("arm_sim", "arm_sim", {"initial_positions": [float(v) for v in args.initial_joints]})
        camera = {**common, "seed": args.seed, **(SIM_CAMERA_WITH_ARM if arm else {})}
        if args.noise:
            camera["noise_preset"] = args.noise
        graph.start_node("sim_camera", "sim_camera", camera)
        box = {"origin": [0.0, 0.0, 0.0], "shape": list(defaults.shape), "voxel_size": defaults.resolution_m}
        still = {"still_frames_fused": STILL_FRAMES_FUSED["noisy" if args.noise else "exact"]}
        integrator = {**box, **still, **(INTEGRATOR_WITH_ARM if arm else {})}
        graph.start_node("integrator", "integrator", integrator)
        graph.start_node("completion_server", "completion_server", common)
        arm_prior = {"use_arm": True, "free_above_m": args.free_above} if arm else {}
        graph.start_node("gain_server", "gain_server", {**common, "completion": "service", **arm_prior})
        planner = {**common, "method": args.method, "in_process": args.in_process}
        if arm:
            planner.update(arm_prior, move_mode=args.move_mode, motion_weight=args.motion_weight)
            planner.update(arm_min_view_height_m=ARM_MIN_VIEW_HEIGHT_M, arm_top_k=20000, arm_max_checks=300)
        graph.start_node("nbv_planner", "nbv_planner", planner)

    client = [
        sys.executable, "-m", "nbv_prob_cnn.ros.explore_client", "--views", str(args.views),
        "--method", args.method, "--stop-unknown", str(args.stop_unknown), "--out", str(out),
        "--title", f"{args.dataset} seed {args.seed}, {args.method}" + (", arm" if arm else ", free-flying camera")
        + (f", {args.noise}" if args.noise else ""),
        "--timeout", str(args.timeout),
        "--world-dataset", args.dataset, "--world-seed", str(args.seed),  # each view's surface coverage
    ]  # fmt: skip
    env = ros_environment(args.domain_id)
    return run_graph(start_nodes, client, env, out / "logs", "explore_sim", timeout_s=args.timeout)


if __name__ == "__main__":
    raise SystemExit(main())
