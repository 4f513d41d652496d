"""``nbv bench --suite arm_loop``: the planning step of the main job (3DT, ``cnn_prob``, the arm in
the loop) through the ROS nodes, stage by stage, against the in-process core on the same grids.

One run does both:

1. **Core**: an arm-constrained exploration in this process with the main job's planner settings
   (:data:`MAIN_JOB_ARM`, the ``explore_sim.py`` values), from the main job's start configuration,
   observing with the ideal sensor. Each step records the grid, the arm's configuration and the
   time per stage: CNN, ranking (ray casting and view search), capability pruning, IK + collision.
2. **Nodes**: ``completion_server``, ``gain_server`` and ``nbv_planner`` (``use_arm``, the same
   settings) in their own processes; this process publishes each recorded grid and configuration
   and calls ``/nbv/plan``, then ``/nbv/complete`` and ``/nbv/rank_views`` on their own (compact
   and per-message replies). The first ``/nbv/plan`` of a fresh graph is the "first view".

The report is a markdown table per step and the medians, with the ratio nodes / core per stage.
"""

from __future__ import annotations

import os
import statistics
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from nbv_prob_cnn.arm.arm_session import SWEPT_STEP  # the swept volume's step, as nbv_planner's
from nbv_prob_cnn.arm.feasibility import FeasibilityReport
from nbv_prob_cnn.arm.selection import ArmViewSelector
from nbv_prob_cnn.arm.swept import SweptVolume
from nbv_prob_cnn.arm.views import ArmPlanningSetup
from nbv_prob_cnn.planners import PlanningContext, ViewChoice

#: The main job's arm start (``launch_scripts/explore_sim.py`` ``LOOK_OVER_TABLE``).
START_Q = (-0.514, -0.296, 0.444, -1.001, 0.161, 1.239, 2.393, 0.04, 0.04)
#: The main job's ``nbv_planner`` arm parameters (``explore_sim.py`` and the node defaults).
MAIN_JOB_ARM = {
    "free_above_m": 0.25, "arm_min_view_height_m": 0.2, "arm_top_k": 20000, "arm_max_checks": 300,
    "capability_stride": 8, "arm_ik_alternatives": 4, "arm_strict_capability": True, "arm_fallback_radius_m": 0.25,
    "arm_carve_swept": True, "motion_weight": 0.0,
}  # fmt: skip


@dataclass
class LoopStep:
    """One planning step of the core exploration: the grid planned on, the arm's configuration,
    the core's choice and its stage times (s)."""

    state: np.ndarray
    q: np.ndarray
    choice: ViewChoice | None
    times: dict[str, float] = field(default_factory=dict)
    checked: int = 0


class HeightLimitedPlanner:
    """A gain planner whose origins are also limited to ``min_height_m`` (``arm_min_view_height_m``),
    as ``nbv_planner`` applies it before the capability filter."""

    takes_view_mask = True

    def __init__(self, planner, geometry, min_height_m: float) -> None:
        self.planner, self.geometry, self.min_height_m = planner, geometry, float(min_height_m)
        self.name = planner.name

    def rank(self, state, context, top_k=1, origin_filter=None, view_mask=None):
        def keep(origins):
            origins = origins[self.geometry.cell_centre(origins)[:, 2] >= self.min_height_m]
            return origins if origin_filter is None else origin_filter(origins)

        return self.planner.rank(state, context, top_k, keep, view_mask=view_mask)


def main_job_setup() -> ArmPlanningSetup:
    """The arm set-up of the main job's planner (default robot)."""
    from nbv_prob_cnn.arm.robot import RobotConfig

    p = MAIN_JOB_ARM
    return ArmPlanningSetup(
        RobotConfig(), float(p["motion_weight"]), float(p["free_above_m"]), int(p["arm_max_checks"]),
        int(p["capability_stride"]), ik_alternatives=int(p["arm_ik_alternatives"]),
        strict_capability=bool(p["arm_strict_capability"]),
    )  # fmt: skip


def core_exploration(seed: int = 1000, views: int = 6, setup: ArmPlanningSetup | None = None) -> list[LoopStep]:
    """The main job's exploration in this process (ideal sensor), one :class:`LoopStep` per plan.

    The first view is the start configuration's camera pose rounded to a planning view (cell and
    orientation nearest to it), as the main job's first frame is taken there.
    """
    from nbv_prob_cnn.basics.camera import quaternion_from_matrix
    from nbv_prob_cnn.planners import GAIN_METHODS, GainPlanner
    from nbv_prob_cnn.planners.requests import choice_from_pose
    from nbv_prob_cnn.sensing.observe import observe
    from nbv_prob_cnn.worlds import load_or_generate

    world = load_or_generate("3dt", seed)
    geometry = world.geometry
    setup = setup or main_job_setup()
    context = PlanningContext.for_dataset("3dt", rng=np.random.default_rng(seed))
    arm = setup.feasibility(geometry)
    swept = SweptVolume(arm.checker, geometry, SWEPT_STEP)
    selector = ArmViewSelector(arm, geometry, swept, float(MAIN_JOB_ARM["arm_fallback_radius_m"]))
    lowest = float(MAIN_JOB_ARM["arm_min_view_height_m"])
    planner = HeightLimitedPlanner(GainPlanner(GAIN_METHODS["cnn_prob"]), geometry, lowest)
    q = setup.robot.configuration(dict(zip(setup.robot.joint_names, START_Q, strict=True)))
    pose = setup.robot.camera_pose(q)
    first = choice_from_pose(pose[:3, 3], quaternion_from_matrix(pose[:3, :3]), 0.0, context, geometry)
    state = np.full(world.shape, -1, dtype=np.int8)
    observe(state, world.ground_truth, first.cell, context.orientations[first.view_index], context.active_sensor)
    swept.add_configuration(q)
    steps: list[LoopStep] = []
    for _ in range(views):
        start = time.perf_counter()
        report = selector.select(planner, state, context, q, int(MAIN_JOB_ARM["arm_top_k"]))
        total = time.perf_counter() - start
        steps.append(_step(state.copy(), q.copy(), report, total))
        if report.view is None:
            break
        selector.moved(q, report.view)
        q = report.view.q
        choice = report.view.choice
        observe(state, world.ground_truth, choice.cell, context.orientations[choice.view_index], context.active_sensor)
    return steps


def _step(state: np.ndarray, q: np.ndarray, report: FeasibilityReport, total: float) -> LoopStep:
    first = report.view.choice.times if report.view is not None else {}
    report = report.total()  # a fallback: both passes' checks and times
    times = {
        "cnn": float(first.get("cnn", 0.0)),
        "rank": float(first.get("raycast", 0.0)) + float(first.get("views", 0.0)),
        "capability": report.times.get("capability", 0.0),
        "ik_collision": report.times.get("ik_collision", 0.0),
        "total": total,
    }
    return LoopStep(state, q, None if report.view is None else report.view.choice, times, report.checked)


@dataclass
class NodeTimes:
    """One ``/nbv/plan`` through the nodes (s) and its side calls."""

    plan: dict[str, float]
    complete: dict[str, float]
    rank: dict[str, float]
    choice: tuple | None


def node_loop(
    steps: list[LoopStep], geometry, domain_id: int | None = None, log_dir=None
) -> tuple[float, list[NodeTimes]]:
    """Each step's grid and configuration through the ROS nodes; returns the seconds from the
    nodes' start to the first answered plan, and per step the plan's stage times plus the
    ``/nbv/complete`` and ``/nbv/rank_views`` round trips on the same grid."""
    import rclpy
    from nbv_prob_cnn_msgs.msg import VoxelGrid
    from nbv_prob_cnn_msgs.srv import CompleteGrid, PlanNextBestView, RankViews
    from rclpy.executors import MultiThreadedExecutor
    from sensor_msgs.msg import JointState

    from nbv_prob_cnn.planners.requests import choice_from_pose
    from nbv_prob_cnn.ros import names
    from nbv_prob_cnn.ros.conversions import grid_to_msg, pose_to_arrays
    from nbv_prob_cnn.ros.graph import NodeGraph, call_with_resend, ros_environment
    from nbv_prob_cnn.ros.qos import GRID_QOS

    env = ros_environment(domain_id)
    os.environ.update({k: env[k] for k in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "RMW_IMPLEMENTATION",
                                             "FASTRTPS_DEFAULT_PROFILES_FILE", "ROS_DOMAIN_ID")})  # fmt: skip
    robot_names = main_job_setup().robot.joint_names
    planner_params = {"dataset": "3dt", "method": "cnn_prob", "use_arm": True, "urdf_path": "panda",
                      "markers_top_k": 1, **MAIN_JOB_ARM}  # fmt: skip
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("arm_loop_bench", context=context)
    executor = MultiThreadedExecutor(num_threads=4, context=context)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    grid_pub = node.create_publisher(VoxelGrid, names.GRID, GRID_QOS)
    joint_pub = node.create_publisher(JointState, names.JOINT_STATES, 10)
    current: dict[str, object] = {}

    def publish_joints() -> None:
        if "q" in current:
            msg = JointState(name=list(robot_names), position=[float(v) for v in current["q"]])  # type: ignore[attr-defined]
            msg.header.stamp = node.get_clock().now().to_msg()
            joint_pub.publish(msg)

    node.create_timer(0.05, publish_joints)
    plan_client = node.create_client(PlanNextBestView, names.PLAN)
    complete_client = node.create_client(CompleteGrid, names.COMPLETE)
    rank_client = node.create_client(RankViews, names.RANK_VIEWS)
    results: list[NodeTimes] = []
    graph = NodeGraph(env, log_dir=log_dir)
    try:
        started = time.perf_counter()
        graph.start_node("completion_server", "completion_server", {"dataset": "3dt"})
        graph.start_node("gain_server", "gain_server", {"dataset": "3dt"})
        graph.start_node("nbv_planner", "nbv_planner", planner_params)
        first_plan = float("nan")
        ctx = PlanningContext.for_dataset("3dt")
        for index, step in enumerate(steps):
            current["q"] = step.q
            msg = grid_to_msg(step.state, geometry)
            msg.header.stamp = node.get_clock().now().to_msg()
            grid_pub.publish(msg)
            time.sleep(0.5)  # the planner's grid and joint state subscriptions get the new ones
            begin = time.perf_counter()
            while True:
                reply = call_with_resend(plan_client, PlanNextBestView.Request(top_k=1), 300.0, resend_s=120.0)
                not_ready = ("no grid", "joint", "not available")  # the graph is still starting
                if reply.success or not any(text in reply.message for text in not_ready):
                    break
                if time.perf_counter() - begin > 300:
                    raise RuntimeError(f"/nbv/plan: {reply.message}")
                time.sleep(0.2)
            round_trip = time.perf_counter() - begin
            if index == 0:
                first_plan = time.perf_counter() - started
            plan = {
                "cnn": reply.time_cnn_s, "rank": reply.time_rank_s, "raycast": reply.time_raycast_s,
                "capability": reply.time_capability_s, "ik_collision": reply.time_ik_collision_s,
                "total": reply.time_total_s, "round_trip": round_trip, "checked": float(reply.arm_checked),
            }  # fmt: skip
            choice = None
            if reply.success:
                position, quaternion = pose_to_arrays(reply.best_pose.pose)
                c = choice_from_pose(position, quaternion, reply.best_gain, ctx, geometry)
                choice = (tuple(int(v) for v in c.cell), c.view_index)
            begin = time.perf_counter()
            asked = CompleteGrid.Request(grid=msg, dataset="3dt")
            done = call_with_resend(complete_client, asked, 120.0, resend_s=60.0)
            complete = {"round_trip": time.perf_counter() - begin, "inference": done.inference_time_s,
                        "server": done.time_total_s}  # fmt: skip
            rank = {}
            for compact in (True, False):
                request = RankViews.Request(grid=msg, method="cnn_prob", top_k=int(MAIN_JOB_ARM["arm_top_k"]),
                                            probability=done.probability, compact=compact)  # fmt: skip
                begin = time.perf_counter()
                answer = call_with_resend(rank_client, request, 120.0, resend_s=60.0)
                key = "compact" if compact else "messages"
                rank[key] = time.perf_counter() - begin
                rank[key + "_server"] = answer.time_total_s
                rank["raycast"] = answer.time_raycast_s + answer.time_views_s
            results.append(NodeTimes(plan, complete, rank, choice))
        alive = graph.alive()
        if not all(alive.values()):
            raise RuntimeError(f"a node stopped during the bench: {alive}")
    finally:
        graph.stop()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        spinner.join(timeout=5)
    return first_plan, results


def _median(values: list[float]) -> float:
    return float(statistics.median(values)) if values else float("nan")


def same_view(step: LoopStep, node: NodeTimes) -> bool:
    """Whether the nodes planned the core's view (cell and orientation)."""
    if step.choice is None:
        return node.choice is None
    return node.choice == (tuple(int(v) for v in step.choice.cell), step.choice.view_index)


def arm_loop_benchmark(seed: int = 1000, views: int = 6, log_dir=None) -> str:
    """Run both halves (see the module doc) and return the markdown report."""
    from nbv_prob_cnn.arm.capability import MAP_IK, capability_key, capability_map_path
    from nbv_prob_cnn.worlds import load_or_generate

    geometry = load_or_generate("3dt", seed).geometry
    setup = main_job_setup()
    cached = capability_map_path(capability_key(setup.robot, geometry, setup.capability_stride, MAP_IK, 2)).is_file()
    begin = time.perf_counter()
    setup.feasibility(geometry)
    core_setup_s = time.perf_counter() - begin
    steps = core_exploration(seed, views, setup)
    first_plan, nodes = node_loop(steps, geometry, log_dir=log_dir)
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    header = (
        "| step | CNN core | CNN nodes (planner's /nbv/complete call) | completion_server: inference / in node / round "
        "trip | rank core | rank nodes / its ray casting | rank_views top 20000: compact / per-message reply | "
        "IK+collision core | IK+collision nodes | checked core / nodes | plan core | plan nodes (round trip) | "
        "same view |"
    )
    lines = [
        (
            f"3DT seed {seed}, cnn_prob, the main job's arm settings; capability map "
            f"{'cached' if cached else 'built'} ({core_setup_s:.1f} s for the core's arm set-up); seconds; "
            f"load average at the end {load}"
        ),
        "",
        header,
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for index, (step, node) in enumerate(zip(steps, nodes, strict=True)):
        c, p, k, r = step.times, node.plan, node.complete, node.rank
        lines.append(
            f"| {index} | {c['cnn']:.2f} | {p['cnn']:.2f} | {k['inference']:.2f} / {k['server']:.2f} / "
            f"{k['round_trip']:.2f} | {c['rank']:.2f} | {p['rank']:.2f} / {p['raycast']:.2f} | "
            f"{r['compact']:.2f} / {r['messages']:.2f} | {c['ik_collision']:.2f} | {p['ik_collision']:.2f} | "
            f"{step.checked} / {int(p['checked'])} | {c['total']:.2f} | {p['total']:.2f} ({p['round_trip']:.2f}) | "
            f"{'yes' if same_view(step, node) else 'no'} |"
        )
    later, core_later = nodes[1:] or nodes, steps[1:] or steps
    plan_times = [n.plan["total"] for n in later]

    def ratio(stage: str, values: list[float]) -> str:
        core = _median([s.times[stage] for s in core_later])
        return f"{_median(values):.2f} s vs {core:.2f} s ({_median(values) / max(core, 1e-9):.2f}x)"

    compact, messages = _median([n.rank["compact"] for n in later]), _median([n.rank["messages"] for n in later])
    lines += [
        "",
        (
            f"first view (nodes started -> first /nbv/plan answered): {first_plan:.1f} s, of which the plan "
            f"{nodes[0].plan['total']:.2f} s"
        ),
        (
            f"plan after the first view through the nodes: median {_median(plan_times):.2f} s, "
            f"max {max(plan_times):.2f} s "
            f"(core: median {_median([s.times['total'] for s in core_later]):.2f} s)"
        ),
        (
            f"CNN, nodes vs core (medians): {ratio('cnn', [n.plan['cnn'] for n in later])}; completion_server's "
            f"inference alone {_median([n.complete['inference'] for n in later]):.2f} s"
        ),
        f"ranking, nodes vs core: {ratio('rank', [n.plan['rank'] for n in later])}",
        f"IK + collision, nodes vs core: {ratio('ik_collision', [n.plan['ik_collision'] for n in later])}",
        f"rank_views round trip, compact vs per-message reply: {compact:.2f} s vs {messages:.2f} s",
    ]
    return "\n".join(lines)
