"""``nbv bench --suite arm_render``: cost per frame of rendering the arm into depth images
(``sim_camera render_arm``) and of filtering it out (``integrator self_filter``), and the fraction
of pixels the filter removes, on a 3DT world with the Panda beside the table."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from nbv_prob_cnn.arm.robot import RobotModel
from nbv_prob_cnn.arm.robot_scene import RobotScene
from nbv_prob_cnn.arm.self_filter import RobotSelfFilter
from nbv_prob_cnn.basics.camera import look_rotation
from nbv_prob_cnn.perception.depth_camera import DepthCamera, Intrinsics, room_mesh

#: External views (eye, target) of the 3DT table with the arm beside its x = 0 face (inside the room
#: walls, 0.3 m outside the grid).
EXTERNAL_VIEWS = {
    "external, front (-y), table and arm": ((0.5, -0.2, 1.1), (0.3, 0.742, 0.3)),
    "external, facing the arm (+x side)": ((1.6, 0.742, 1.0), (0.0, 0.742, 0.4)),
}


def look_at(eye, target) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = look_rotation(np.asarray(target, dtype=np.float64) - np.asarray(eye, dtype=np.float64))
    pose[:3, 3] = eye
    return pose


def median_ms(function: Callable[[int], object], repeats: int) -> float:
    """Median wall time of ``function(i)`` over ``repeats`` calls, in milliseconds."""
    seconds = []
    for i in range(repeats):
        start = time.perf_counter()
        function(i)
        seconds.append(time.perf_counter() - start)
    return 1000.0 * float(np.median(seconds))


def arm_render_benchmark(seed: int = 1000, repeats: int = 10, width: int = 640, height: int = 480) -> str:
    """Run the benchmark; return a printable Markdown report."""
    from nbv_prob_cnn.worlds import load_or_generate

    world = load_or_generate("3dt", seed)
    lower = np.asarray(world.origin, dtype=np.float64) - 0.3
    meshes = [*world.triangle_meshes(), room_mesh(lower, lower + np.asarray(world.shape) * world.resolution + 0.6)]
    intrinsics = Intrinsics.from_hfov(width, height, 60.0)
    camera = DepthCamera(meshes, intrinsics)
    robot = RobotModel()
    q0 = robot.reference_q
    rng = np.random.default_rng(seed)
    # a moving arm: a new configuration each frame (small steps about the reference)
    moving = [np.clip(q0 + rng.normal(0.0, 0.05, q0.shape), robot.lower, robot.upper) for _ in range(repeats)]
    visual = RobotScene(robot, "visual")
    start = time.perf_counter()
    self_filter = RobotSelfFilter(robot, "both")
    load_ms = 1000.0 * (time.perf_counter() - start)
    views = {"hand camera, ready pose": robot.camera_pose(q0)}
    views.update({name: look_at(eye, target) for name, (eye, target) in EXTERNAL_VIEWS.items()})

    triangles = sum(len(mesh.faces) for mesh in visual.meshes)
    header = (
        f"3DT world seed {seed} in a room, Panda beside the table, {width}x{height} px; median of {repeats} frames "
        f"(ms); arm rendered with its {len(visual.meshes)} visual meshes ({triangles} triangles), filtered with the "
        f"{len(self_filter.scene.meshes)} collision + visual bodies (loaded in {load_ms:.0f} ms); 'moving' = a new "
        "joint state every frame (scene rebuilt), 'resting' = the same joint state (scene kept)"
    )
    columns = (
        "| view | render scene | + arm resting | + arm moving | filter resting | filter moving | "
        "render ratio resting / moving | pixels filtered |"
    )
    lines = [header, "", columns, "|---|---|---|---|---|---|---|---|"]
    for name, pose in views.items():
        depth = camera.render(pose, [visual.scene(q0)])

        def render(i: int, pose: np.ndarray = pose) -> object:
            return camera.render(pose)

        def render_resting(i: int, pose: np.ndarray = pose) -> object:
            return camera.render(pose, [visual.scene(q0)])

        def render_moving(i: int, pose: np.ndarray = pose) -> object:
            return camera.render(pose, [visual.scene(moving[i])])

        def filter_resting(i: int, pose: np.ndarray = pose, depth: np.ndarray = depth) -> object:
            return self_filter.filter(depth, q0, intrinsics, pose)

        def filter_moving(i: int, pose: np.ndarray = pose, depth: np.ndarray = depth) -> object:
            return self_filter.filter(depth, moving[i], intrinsics, pose)

        plain, resting, moving_ms, resting_filter, moving_filter = (
            median_ms(function, repeats)
            for function in (render, render_resting, render_moving, filter_resting, filter_moving)
        )
        arm = self_filter.mask(depth, q0, intrinsics, pose)
        lines.append(
            f"| {name} | {plain:.1f} | {resting:.1f} | {moving_ms:.1f} | {resting_filter:.1f} | {moving_filter:.1f} | "
            f"{resting / plain:.2f} / {moving_ms / plain:.2f} | {100.0 * arm.sum() / arm.size:.2f} % |"
        )
    return "\n".join(lines)
