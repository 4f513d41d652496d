"""``nbv bench --suite arm``: capability-map build, IK time, map accuracy, and the cost the arm adds
to one 3DT planning iteration (measured side by side with the free-flying plan in one run)."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from nbv_prob_cnn.arm.capability import build_capability_map, chain_reach, view_rotations
from nbv_prob_cnn.arm.collision import CollisionChecker
from nbv_prob_cnn.arm.feasibility import ArmFeasibility, plan_with_arm
from nbv_prob_cnn.arm.ik import solve_camera_pose
from nbv_prob_cnn.arm.kinematics import CameraChain
from nbv_prob_cnn.arm.robot import RobotModel


@dataclass
class MapAccuracy:
    """Capability map against exact IK on sampled (cell, orientation) pairs within reach."""

    true_positive: int = 0
    false_negative: int = 0
    false_positive: int = 0
    true_negative: int = 0

    @property
    def false_negative_rate(self) -> float:
        positives = self.true_positive + self.false_negative
        return self.false_negative / positives if positives else 0.0


def map_accuracy(
    robot, capability, geometry, samples: int, rng: np.random.Generator, strict: bool = False
) -> tuple[MapAccuracy, list]:
    """Sample cells within the chain's reach and random orientations; compare with exact IK
    (``strict``: the AND lookup of :meth:`CapabilityMap.views_at`). Returns the counts and the
    seconds of each IK solve."""
    chain = CameraChain(robot)
    first, reach = chain_reach(chain)
    rotations = view_rotations()
    accuracy, seconds = MapAccuracy(), []
    while sum(vars(accuracy).values()) < samples:
        cell = rng.integers(0, geometry.shape)
        if np.linalg.norm(geometry.cell_centre(cell) - first) > reach:
            continue
        view = int(rng.integers(len(rotations)))
        target = np.eye(4)
        target[:3, :3] = rotations[view]
        target[:3, 3] = geometry.cell_centre(cell)
        start = time.perf_counter()
        exact = solve_camera_pose(chain, target, robot.reference_q, rng).q is not None
        seconds.append(time.perf_counter() - start)
        mapped = bool(capability.views_at(cell[None], strict)[0, view])
        if exact and mapped:
            accuracy.true_positive += 1
        elif exact:
            accuracy.false_negative += 1
        elif mapped:
            accuracy.false_positive += 1
        else:
            accuracy.true_negative += 1
    return accuracy, seconds


def arm_benchmark(
    seed: int = 1000,
    stride: int = 8,
    method: str = "prob_ig",
    top_k: int = 1000,
    iterations: int = 3,
    samples: int = 300,
    free_above_m: float | None = 0.25,
    max_checks: int = 30,
    ik_alternatives: int = 4,
    strict_capability: bool = True,
) -> str:
    """Run the arm benchmark on the 3DT world ``seed``; return a printable report."""
    from nbv_prob_cnn.bench.planning import half_explored
    from nbv_prob_cnn.planners import GAIN_METHODS, GainPlanner, PlanningContext
    from nbv_prob_cnn.worlds import load_or_generate

    lines = []
    rng = np.random.default_rng(seed)
    world = load_or_generate("3dt", seed)
    geometry = world.geometry
    robot = RobotModel()
    start = time.perf_counter()
    checker = CollisionChecker(robot, spacing=0.75 * geometry.resolution)
    lines.append(
        f"collision model: {time.perf_counter() - start:.2f} s, {checker.n_pairs} self-collision pairs, "
        f"{sum(len(p) for p in checker.points.values())} grid sample points"
    )
    capability = build_capability_map(robot, geometry, stride)
    reachable = capability.reachable
    lines.append(
        f"capability map (stride {stride} cells = {stride * geometry.resolution * 100:.1f} cm): built in "
        f"{capability.build_seconds:.1f} s, table {reachable.shape} = {reachable.size} entries "
        f"({reachable.nbytes / 1e6:.2f} MB as bool, {np.packbits(reachable).nbytes / 1e3:.0f} kB packed), "
        f"{100 * capability.reachable_fraction:.1f} % reachable"
    )
    for strict in (False, True):
        accuracy, seconds = map_accuracy(robot, capability, geometry, samples, np.random.default_rng(seed), strict)
        lines.append(
            f"map ({'AND' if strict else 'OR'} of the surrounding nodes) vs exact IK on {samples} samples within "
            f"reach: {vars(accuracy)}, false-negative rate {100 * accuracy.false_negative_rate:.1f} %"
        )
    lines.append(
        f"IK per camera pose (9 seeds, stops at the first): median {1000 * np.median(seconds):.1f} ms, "
        f"p90 {1000 * np.percentile(seconds, 90):.1f} ms"
    )

    context = PlanningContext.for_dataset("3dt", rng=np.random.default_rng(seed))
    planner = GainPlanner(GAIN_METHODS[method])
    arm = ArmFeasibility(
        robot,
        checker,
        capability=capability,
        free_above_m=free_above_m,
        max_checks=max_checks,
        rng=rng,
        ik_alternatives=ik_alternatives,
        strict_capability=strict_capability,
    )
    lines.append("")
    lines.append(
        f"per planning iteration ({method}, 3DT seed {seed}, explored by random views to 60/50/40 % unknown, "
        f"top_k {top_k}, unknown free above {free_above_m} m, at most {max_checks} exact checks, "
        f"{ik_alternatives} IK alternatives, capability lookup {'AND' if strict_capability else 'OR'}):"
    )
    lines.append(
        "iter | free-flying s | arm total s | gain s | capability s | ik+collision s | arm stages s | added s | checked"
    )
    added_all, stages_all = [], []
    for iteration in range(iterations):
        state = half_explored(world, context, target=0.6 - 0.1 * iteration)
        begin = time.perf_counter()
        planner.rank(state, context, top_k=1)
        free = time.perf_counter() - begin
        begin = time.perf_counter()
        report = plan_with_arm(planner, state, context, geometry, arm, robot.reference_q, top_k=top_k)
        total = time.perf_counter() - begin
        added = total - free
        added_all.append(added)
        t = report.times
        stages = t["capability"] + t["ik_collision"]
        stages_all.append(stages)
        lines.append(
            f"{iteration} | {free:.3f} | {total:.3f} | {t['gain']:.3f} | {t['capability']:.3f} | "
            f"{t['ik_collision']:.3f} | {stages:.3f} | {added:+.3f} | "
            f"{report.checked} (hand blocked before IK {report.camera_blocked}, unreachable {report.unreachable}, "
            f"collision {report.in_collision}, path {report.path_blocked}, found {report.view is not None})"
        )
    lines.append(
        f"added cost per iteration (target <= 0.3 s): arm stages (capability + IK/collision) median "
        f"{np.median(stages_all):.3f} s, max {np.max(stages_all):.3f} s; arm total - free-flying median "
        f"{np.median(added_all):+.3f} s (the arm's gain stage sees fewer origins; both timed in this run)"
    )
    return "\n".join(lines)
