"""``nbv study robot_plans``: how long the example robot files' plans take through ``launch_scripts/robot.py``
(issue 46 item 5): per parameters file, the first and median plan, the planner's stages, the fallbacks.

For each example parameters file (``nbv_prob_cnn/ros/config/panda_d435.yaml``, ``ur5e_d435.yaml``) a
robot graph stands in for the drivers under the names the file expects: ``arm_sim`` (the robot
model, the joints and the ``FollowJointTrajectory`` action of the file's ``trajectory_action``, the
camera in the file's ``camera_frame`` on its ``camera_parent``) and ``sim_camera`` (16UC1 depth and
CameraInfo of a D435-like 87 deg camera riding on the arm, the arm rendered in). Then
``robot.py --params-file <file> --views N`` explores, and the study reads each plan's times from
the planner's log line ``view i: ...; plan T s (CNN, ray casting, views, rank reply, capability,
IK+collision (n checked), other), move M s, grid wait W s``: the plan time is ``T``, without the
arm's move and the wait for the grid.

* Panda: ``arm_sim``'s built-in Panda 10 cm before the grid's x = 0 face, the scene the 3DT world of
  ``--seed`` (as ``test/ros/test_robot_launch.py``).
* UR5e: no UR5e model ships here, so :func:`ur5e_like_urdf` builds one: the UR5e's kinematics
  (``ur_description``'s ur5e joint origins, limits +-2 pi, elbow +-pi, 3.14 rad/s) with cylinders
  for the links and a box for the camera on ``tool0``, its base on a stand at the table top's
  height (:data:`UR5E_BASE_XYZ`) 25 cm before the grid's x face. The 3DT world (and
  ``sim_camera``'s room) moves to the file's grid ``origin`` (a mesh file), so the table top is
  where the file expects it (world z 0.76-0.78 m).

Unless ``--careful-speeds``, the planner moves the arm at its full URDF speeds (the files' 0.2 of
them and their acceleration and jerk limits make the moves slow, as in ``test_robot_launch``): that
changes the move time, not the plan time. ``--set node.name=value`` overrides a parameter of the
file (e.g. ``nbv_planner.min_camera_height_m=0.2``, the Panda file's old floor). The load average
is sampled every 2 s during each run and reported with the plans.

Writes to ``--out``: ``plans.csv`` (one row per plan), ``runs.csv`` (one row per run), ``summary.md``
and ``plan_times.png``, and ``<label>/`` (the run's ``views.csv``, ``nbv_planner.log`` and
``cpu_sharers.txt``: the busiest processes 30 s into the run). Runs of
another label already in ``--out`` are kept, so variants add up in one summary; ``plans.csv`` is
rebuilt from the saved logs each time, with the ``arm check:`` line before each plan (every pass:
a fallback plan's first pass too, which the plan line's count omitted before commit fe1a103). ``--files`` with no file
writes the summary and the figure again; ``--method`` sets the Explore goal's method.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import re
import shutil
import statistics
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from studies._command import run_command

HELP = "First and median plan of the example robot parameters files through launch_scripts/robot.py."
REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "nbv_prob_cnn" / "ros" / "config"
EXAMPLES = ("panda_d435.yaml", "ur5e_d435.yaml")
#: The Panda's joints looking over the table (test_robot_launch's start).
PANDA_START = [-0.514, -0.296, 0.444, -1.001, 0.161, 1.239, 2.393, 0.04, 0.04]
#: The UR5e-like arm's base (world, m): on a stand at the table top's height, 25 cm before the grid.
UR5E_BASE_XYZ = [0.0, 0.0, 0.77]
#: Its start: the camera 0.75 m above the table top at x 0.45 m, looking 43 deg down along +x.
UR5E_START = [0.0, -1.7, 1.2, -1.9, -1.57, 0.0]
#: The optical frame on tool0 (m): at the camera box's front face, looking along tool0's z.
UR5E_CAMERA_XYZ = [0.0, 0.0, 0.03]
#: The speeds of a fast run (nbv_planner parameters), as test_robot_launch.
FAST = {"trajectory_velocity_scale": 1.0, "max_joint_acceleration": 4.0, "max_joint_jerk": 40.0}
#: The blocks of a parameters file --set may change (robot.py's nodes and the shared block).
NODE_BLOCKS = ("/**", "integrator", "completion_server", "gain_server", "nbv_planner")
#: The planner's per-view log line (nbv_prob_cnn.exploration.step_log.stage_times).
VIEW_LINE = re.compile(
    r"view (?P<view>\d+)(?P<fallback> \(fallback[^)]*\))?: .*?; plan (?P<plan_s>[\d.]+) s \(CNN (?P<cnn_s>[\d.]+), "
    r"ray casting (?P<raycast_s>[\d.]+), views (?P<views_s>[\d.]+)(?:, rank reply (?P<rank_reply_s>[\d.]+), "
    r"capability (?P<capability_s>[\d.]+), IK\+collision (?P<ik_collision_s>[\d.]+) \((?P<checked>\d+) checked\))?, "
    r"other (?P<other_s>[\d.]+)\), move (?P<move_s>[\d.]+) s, grid wait (?P<grid_wait_s>[\d.]+) s"
)
ARM_CHECKED = re.compile(r"(\d+) checked of \d+ candidates")
IN_COLLISION = re.compile(r"(\d+) in collision")
FAILED_MOVE = re.compile(r"view \d+: move failed")
SET_UP = re.compile(r"arm set-up for the grid \(capability map, collision model\): (?P<s>[\d.]+) s")
#: The plan's stages, as the log names them (the plan time is their sum up to rounding).
STAGES = ("cnn_s", "raycast_s", "views_s", "rank_reply_s", "capability_s", "ik_collision_s", "other_s")
PLAN_COLUMNS = (
    "label",
    "view",
    "fallback",
    "plan_s",
    *STAGES,
    "checked",
    "arm_checked",
    "in_collision",
    "move_s",
    "grid_wait_s",
)
RUN_COLUMNS = ("label", "file", "overrides", "speeds", "views_asked", "plans", "first_plan_s", "median_plan_s",
               "max_plan_s", "first_checked", "fallbacks", "failed_moves", "final_unknown", "arm_set_up_s", "load_min",
               "load_mean", "load_max", "wall_s", "exit", "started_utc")  # fmt: skip

Vec3 = tuple[float, float, float]
#: name, parent, child, xyz, rpy, limit (rad; None = fixed): ur_description's ur5e joints
UR5E_JOINTS: tuple[tuple[str, str, str, Vec3, Vec3, float | None], ...] = (
    ("base_link-base_link_inertia", "base_link", "base_link_inertia", (0, 0, 0), (0, 0, math.pi), None),
    ("shoulder_pan_joint", "base_link_inertia", "shoulder_link", (0, 0, 0.1625), (0, 0, 0), 2 * math.pi),
    ("shoulder_lift_joint", "shoulder_link", "upper_arm_link", (0, 0, 0), (math.pi / 2, 0, 0), 2 * math.pi),
    ("elbow_joint", "upper_arm_link", "forearm_link", (-0.425, 0, 0), (0, 0, 0), math.pi),
    ("wrist_1_joint", "forearm_link", "wrist_1_link", (-0.3922, 0, 0.1333), (0, 0, 0), 2 * math.pi),
    ("wrist_2_joint", "wrist_1_link", "wrist_2_link", (0, -0.0997, 0), (math.pi / 2, 0, 0), 2 * math.pi),
    ("wrist_3_joint", "wrist_2_link", "wrist_3_link", (0, 0.0996, 0), (math.pi / 2, math.pi, math.pi), 2 * math.pi),
    ("wrist_3-flange", "wrist_3_link", "flange", (0, 0, 0), (0, -math.pi / 2, -math.pi / 2), None),
    ("flange-tool0", "flange", "tool0", (0, 0, 0), (math.pi / 2, 0, math.pi / 2), None),
    ("tool0-camera_link", "tool0", "camera_link", (0, 0, 0), (0, 0, 0), None),
)
_ALONG_X: Vec3 = (0, math.pi / 2, 0)
_ALONG_Y: Vec3 = (math.pi / 2, 0, 0)
#: link: (shape, size, xyz, rpy); cylinders (radius, length) along the link's tube
UR5E_BODIES: dict[str, tuple[str, tuple[float, ...], Vec3, Vec3]] = {
    "base_link": ("cylinder", (0.075, 0.09), (0, 0, 0.045), (0, 0, 0)),
    "shoulder_link": ("cylinder", (0.06, 0.135), (0, 0, 0), (0, 0, 0)),
    "upper_arm_link": ("cylinder", (0.054, 0.5), (-0.2125, 0, 0.138), _ALONG_X),
    "forearm_link": ("cylinder", (0.04, 0.45), (-0.196, 0, 0.007), _ALONG_X),
    "wrist_1_link": ("cylinder", (0.045, 0.12), (0, -0.045, 0), _ALONG_Y),
    "wrist_2_link": ("cylinder", (0.045, 0.12), (0, 0.045, 0), _ALONG_Y),
    "wrist_3_link": ("cylinder", (0.045, 0.04), (0, 0, -0.02), (0, 0, 0)),
    "camera_link": ("box", (0.09, 0.025, 0.025), (0, 0, 0.0125), (0, 0, 0)),
}


def _xyz(values) -> str:
    return " ".join(f"{float(v):.9g}" for v in values)


def ur5e_like_urdf() -> str:
    """URDF of a UR5e-like arm: the UR5e's kinematic chain base_link .. tool0 with primitive bodies."""
    links = ["base_link", "base_link_inertia", *(j[2] for j in UR5E_JOINTS[1:])]
    parts = ['<?xml version="1.0"?>', '<robot name="ur5e_like">']
    for name in links:
        body = ""
        if name in UR5E_BODIES:
            shape, size, xyz, rpy = UR5E_BODIES[name]
            geometry = (f'<cylinder radius="{size[0]}" length="{size[1]}"/>' if shape == "cylinder"
                        else f'<box size="{_xyz(size)}"/>')  # fmt: skip
            element = f'<origin xyz="{_xyz(xyz)}" rpy="{_xyz(rpy)}"/><geometry>{geometry}</geometry>'
            body = f"<visual>{element}</visual><collision>{element}</collision>"
        parts.append(f'<link name="{name}">{body}</link>')
    for name, parent, child, xyz, rpy, limit in UR5E_JOINTS:
        kind = "fixed" if limit is None else "revolute"
        joint = (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
                 f'<origin xyz="{_xyz(xyz)}" rpy="{_xyz(rpy)}"/>')  # fmt: skip
        if limit is not None:
            limits = f'lower="{-limit:.9g}" upper="{limit:.9g}" effort="150" velocity="3.14159"'
            joint += f'<axis xyz="0 0 1"/><limit {limits}/>'
        parts.append(joint + "</joint>")
    parts.append("</robot>")
    return "\n".join(parts) + "\n"


def shifted_scene(seed: int, origin: list[float], path: Path) -> Path:
    """The 3DT world of ``seed`` with its room (0.3 m margin), moved so that its grid's corner is at
    ``origin`` (world, m), written to ``path`` (a mesh ``sim_camera`` reads as ``mesh_file``)."""
    import numpy as np
    import trimesh

    from nbv_prob_cnn.ros.sim_camera import load_meshes
    from nbv_prob_cnn.worlds import load_or_generate

    meshes, _ = load_meshes("3dt", seed, "", 0.3)
    scene = trimesh.util.concatenate(meshes)
    scene.apply_translation(np.asarray(origin, dtype=np.float64) - np.asarray(load_or_generate("3dt", seed).origin))
    scene.export(path)
    return path


def stand_in(params: dict, run_dir: Path, seed: int) -> tuple[dict, dict]:
    """``arm_sim`` and ``sim_camera`` parameters that pose as the drivers a parameters file expects."""
    shared = params["/**"]["ros__parameters"]
    planner = params["nbv_planner"]["ros__parameters"]
    origin = list(params["integrator"]["ros__parameters"]["origin"])
    frame, parent = shared["camera_frame"], shared["camera_parent"]
    arm = {"camera_frame": frame, "controller_action": planner["trajectory_action"].lstrip("/"),
           "velocity_scale": 1.0}  # fmt: skip
    camera = {"camera_frame": frame, "follow_arm": True, "render_arm": True, "encoding": "16UC1", "hfov_deg": 87.0,
              "seed": seed}  # fmt: skip
    if parent == "panda_hand":
        if any(abs(v) > 1e-9 for v in origin):
            raise ValueError(f"panda stand-in: arm_sim's Panda stands before a grid at the origin, not {origin}")
        arm["initial_positions"] = PANDA_START
    elif parent == "tool0":
        urdf = run_dir / "ur5e_like.urdf"
        urdf.write_text(ur5e_like_urdf())
        arm.update(urdf_path=str(urdf), camera_parent="tool0", camera_xyz=UR5E_CAMERA_XYZ, base_xyz=UR5E_BASE_XYZ,
                   initial_positions=UR5E_START)  # fmt: skip
        camera["mesh_file"] = str(shifted_scene(seed, origin, run_dir / "scene.ply"))
    else:
        raise ValueError(f"camera_parent {parent!r}: no stand-in robot (panda_hand: the Panda, tool0: a UR5e-like arm)")
    return arm, camera


def apply_overrides(params: dict, overrides: list[str], fast: bool) -> dict:
    """The file's parameters with ``node.name=value`` overrides (YAML values) and, when ``fast``, the fast speeds."""
    if fast:
        params["nbv_planner"]["ros__parameters"].update(FAST)
    for item in overrides:
        key, sep, value = item.partition("=")
        node, dot, name = key.partition(".")
        if not sep or not dot or node not in NODE_BLOCKS:
            raise ValueError(f"--set: expected NODE.NAME=VALUE with NODE one of {', '.join(NODE_BLOCKS)}, got {item!r}")
        params.setdefault(node, {"ros__parameters": {}})["ros__parameters"][name] = yaml.safe_load(value)
    return params


def parse_plans(log_text: str) -> tuple[list[dict], int, float | None]:
    """Each plan's times from a planner log, the failed moves and the arm set-up time (s, None: not logged)."""
    rows = []
    previous_end = 0
    for match in VIEW_LINE.finditer(log_text):
        found = match.groupdict()
        row: dict = {"view": int(found["view"]), "fallback": int(found["fallback"] is not None)}
        for key in ("plan_s", *STAGES, "move_s", "grid_wait_s"):
            row[key] = float(found[key]) if found.get(key) is not None else 0.0
        row["checked"] = int(found["checked"]) if found["checked"] is not None else 0
        # the arm check line before the plan's: every pass (a fallback's first pass, which "checked" omitted
        # in the shipped runs, made before commit fe1a103; it counts both passes now)
        start = log_text.rfind("arm check: ", previous_end, match.start())
        arm = log_text[start : match.start()] if start >= 0 else ""
        previous_end = match.end()
        row["arm_checked"] = sum(int(n) for n in ARM_CHECKED.findall(arm))
        row["in_collision"] = sum(int(n) for n in IN_COLLISION.findall(arm))
        rows.append(row)
    set_up = SET_UP.search(log_text)
    return rows, len(FAILED_MOVE.findall(log_text)), float(set_up["s"]) if set_up else None


def plan_summary(plan_s: list[float]) -> dict:
    """First, median and largest plan time (s; NaN without plans)."""
    if not plan_s:
        return {"first_plan_s": math.nan, "median_plan_s": math.nan, "max_plan_s": math.nan}
    return {"first_plan_s": plan_s[0], "median_plan_s": statistics.median(plan_s), "max_plan_s": max(plan_s)}


def dominant_stage(rows: list[dict]) -> tuple[str, float]:
    """The stage with the largest median time over ``rows`` and that median (s)."""
    medians = {stage: statistics.median(float(r[stage]) for r in rows) for stage in STAGES}
    stage = max(medians, key=lambda s: medians[s])
    return stage, medians[stage]


def cpu_sharers(count: int = 8) -> str:
    """The ``count`` busiest processes now (``ps``: pid, nice, %CPU over the process's life, command line cut)."""
    listing = subprocess.run(["ps", "-eo", "pid,ni,pcpu,args", "--sort=-pcpu"], capture_output=True, text=True)
    return "".join(line[:130] + "\n" for line in listing.stdout.splitlines()[: count + 1])


#: When the sampler notes which processes share the CPU (samples of period_s: 30 s into the run).
SHARERS_AFTER_SAMPLES = 15


@dataclass
class LoadSampler:
    """The 1-minute load average every ``period_s`` in a background thread."""

    period_s: float = 2.0
    samples: list[float] = field(default_factory=list)
    sharers: str = ""  # the busiest processes, once, SHARERS_AFTER_SAMPLES samples in
    _stop: threading.Event = field(default_factory=threading.Event)

    def __enter__(self) -> LoadSampler:
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()
        return self

    def _loop(self) -> None:
        while True:
            self.samples.append(os.getloadavg()[0])
            if len(self.samples) == SHARERS_AFTER_SAMPLES:
                self.sharers = cpu_sharers()
            if self._stop.wait(self.period_s):
                return

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


def read_csv(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    with open(path) as handle:
        return list(csv.DictReader(handle))


def write_csv(path: Path, columns: tuple[str, ...], rows: list[dict]) -> None:
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)


def _fmt(value) -> str:
    return f"{value:.3f}" if isinstance(value, float) else str(value)


def run_file(path: Path, label: str, args: argparse.Namespace, run_dir: Path) -> tuple[dict, list[dict]]:
    """One exploration of ``--views`` views with the parameters file ``path`` beside its stand-in robot graph."""
    from nbv_prob_cnn.ros.graph import NodeGraph, free_domain_id, ros_environment

    run_dir.mkdir(parents=True, exist_ok=True)
    params = apply_overrides(yaml.safe_load(path.read_text()), args.set, not args.careful_speeds)
    params_file = run_dir / path.name
    params_file.write_text(yaml.safe_dump(params))
    arm, camera = stand_in(params, run_dir, args.seed)
    env = ros_environment(args.domain_id if args.domain_id is not None else free_domain_id())
    cmd = [sys.executable, str(REPO / "launch_scripts" / "robot.py"), "--params-file", str(params_file),
           "--views", str(args.views), "--out", str(run_dir / "run"), "--timeout", str(args.timeout)]  # fmt: skip
    if args.method:
        cmd += ["--method", args.method]
    started = time.strftime("%Y-%m-%d %H:%M", time.gmtime())
    print(f"[robot_plans] {label}: ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']}, {' '.join(cmd)}", flush=True)
    start = time.monotonic()
    with NodeGraph(env, log_dir=run_dir / "robot_logs") as robot, LoadSampler() as load:
        robot.start_node("arm_sim", "arm_sim", arm)
        robot.start_node("sim_camera", "sim_camera", camera)
        done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=args.timeout + 120)
    (run_dir / "robot_py.out").write_text(done.stdout + done.stderr)
    (run_dir / "cpu_sharers.txt").write_text(load.sharers)
    log_path = run_dir / "run" / "logs" / "nbv_planner.log"
    plans, failed, set_up = parse_plans(log_path.read_text() if log_path.is_file() else "")
    overrides = " ".join(args.set + ([f"method {args.method}"] if args.method else []))
    run = {"label": label, "file": str(path.relative_to(REPO)) if path.is_relative_to(REPO) else str(path),
           "overrides": overrides, "speeds": "file" if args.careful_speeds else "fast", "views_asked":
           args.views, "plans": len(plans), **plan_summary([p["plan_s"] for p in plans]),
           "first_checked": plans[0]["arm_checked"] if plans else 0, "fallbacks": sum(p["fallback"] for p in plans),
           "failed_moves": failed, "final_unknown": final_unknown(run_dir / "run" / "views.csv"),
           "arm_set_up_s": set_up if set_up is not None else math.nan, "load_min": min(load.samples),
           "load_mean": statistics.fmean(load.samples), "load_max": max(load.samples),
           "wall_s": time.monotonic() - start, "exit": done.returncode, "started_utc": started}  # fmt: skip
    return run, [{"label": label, **p} for p in plans]


def final_unknown(views_csv: Path) -> float:
    """The unknown fraction after the last view of an exploration's ``views.csv`` (NaN: no view)."""
    rows = read_csv(views_csv)
    return float(rows[-1]["unknown_fraction"]) if rows else math.nan


def write_summary(out: Path, runs: list[dict], plans: list[dict], notes: list[str]) -> None:
    """``summary.md`` of every run in ``out`` (rows as read back from the CSVs)."""
    lines = [
        "# Plan times of the example robot files through launch_scripts/robot.py",
        "",
        (
            "Made by `nbv study robot_plans` (studies/robot_plans.py; what stands in for the drivers: its docstring). "
            "Plan = the planner's own plan time (CNN, ranking, arm check), not the arm's move or the wait for the grid."
        ),
        "",
        (
            "| label | file | overrides | speeds | plans | first (s) | median (s) | max (s) | first plan's checks "
            "| fallbacks | failed moves | unknown after the last | arm set-up (s) | load avg 1 min min/mean/max | exit "
            "| started (UTC) |"
        ),
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in runs:
        lines.append(
            f"| {r['label']} | `{r['file']}` | {r['overrides'] or '-'} | {r['speeds']} | {r['plans']} | "
            f"{float(r['first_plan_s']):.2f} | {float(r['median_plan_s']):.2f} | {float(r['max_plan_s']):.2f} | "
            f"{r['first_checked']} | {r['fallbacks']} | {r['failed_moves']} | {float(r['final_unknown']):.4f} | "
            f"{float(r['arm_set_up_s']):.1f} | {float(r['load_min']):.1f} / "
            f"{float(r['load_mean']):.1f} / {float(r['load_max']):.1f} | {r['exit']} | {r['started_utc']} |"
        )
    lines += ["", "Median time per stage (s) over each run's plans, and the views the arm check tried:", "",
              "| label | " + " | ".join(STAGES) + " | views checked median / max | largest stage |",
              "|---|" + "---|" * (len(STAGES) + 2)]  # fmt: skip
    for r in runs:
        mine = [p for p in plans if p["label"] == r["label"]]
        if not mine:
            continue
        stage, seconds = dominant_stage(mine)
        checked = [int(p["arm_checked"]) for p in mine]
        medians = " | ".join(f"{statistics.median(float(p[s]) for p in mine):.2f}" for s in STAGES)
        lines.append(f"| {r['label']} | {medians} | {statistics.median(checked):g} / {max(checked)} | "
                     f"{stage} ({seconds:.2f} s) |")  # fmt: skip
    lines += [""] + [f"* {note}" for note in notes]
    (out / "summary.md").write_text("\n".join(lines) + "\n")


def plot(out: Path, runs: list[dict], plans: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = sorted({Path(r["file"]).name for r in runs})
    fig, axes = plt.subplots(1, max(1, len(files)), figsize=(6.5 * max(1, len(files)), 4.2), squeeze=False)
    for ax, name in zip(axes[0], files, strict=False):
        for r in (r for r in runs if Path(r["file"]).name == name):
            mine = [p for p in plans if p["label"] == r["label"]]
            views = [int(p["view"]) + 1 for p in mine]
            ax.plot(views, [float(p["plan_s"]) for p in mine], marker="o",
                    label=f"{r['label']} (load {float(r['load_mean']):.1f})")  # fmt: skip
            falls = [(v, float(p["plan_s"])) for v, p in zip(views, mine, strict=True) if int(p["fallback"])]
            if falls:
                ax.plot(*zip(*falls, strict=True), "kx", markersize=10)
        ax.axhline(1.5, color="grey", linestyle="--", linewidth=1, label="target median 1.5 s")
        ax.set_xlabel("view (plan number)")
        ax.set_ylabel("plan time (s)")
        ax.set_title(f"{name} through robot.py (x: near-camera fallback)", fontsize=10)
        ax.set_ylim(bottom=0)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "plan_times.png", dpi=110)
    plt.close(fig)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--files", nargs="*", type=Path, default=[CONFIG / name for name in EXAMPLES],
                        help="parameters files (default: the two examples; none: only write the summary and figure "
                        "again from --out's CSVs and notes)")  # fmt: skip
    parser.add_argument("--views", type=int, default=10, help="views per run (default 10)")
    parser.add_argument("--out", type=Path, default=Path("out/robot_plans"), help="results directory")
    parser.add_argument("--set", action="append", default=[], metavar="NODE.NAME=VALUE",
                        help="override a parameter of every file (YAML value)")  # fmt: skip
    parser.add_argument("--method", default="", help="the Explore goal's method (default: the file's)")
    parser.add_argument("--label-suffix", default="", help="appended to each run's label (the file's stem)")
    parser.add_argument("--careful-speeds", action="store_true", help="keep the files' slow arm speeds")
    parser.add_argument("--seed", type=int, default=1000, help="3DT world seed of the scene (default 1000)")
    parser.add_argument("--timeout", type=float, default=1200.0, help="robot.py --timeout per run (s)")
    parser.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID (default: derived from the pid)")
    parser.add_argument("--work", type=Path, default=Path("/tmp/robot_plans"), help="run directories (logs, grids)")
    parser.add_argument("--note", action="append", default=[], help="a line for the summary (kept with the runs)")


def run(args: argparse.Namespace) -> int:
    if args.views < 1:
        raise ValueError(f"--views: expected >= 1, got {args.views}")
    args.out.mkdir(parents=True, exist_ok=True)
    runs, plans = read_csv(args.out / "runs.csv"), read_csv(args.out / "plans.csv")
    status = 0
    for path in args.files:
        if not path.is_file():
            raise FileNotFoundError(f"--files: no such file {path}")
        label = path.stem + args.label_suffix
        run_, plans_ = run_file(path.resolve(), label, args, args.work / label)
        saved = args.out / label
        saved.mkdir(exist_ok=True)
        for name in ("run/views.csv", "run/logs/nbv_planner.log", "cpu_sharers.txt"):
            if (args.work / label / name).is_file():
                shutil.copy(args.work / label / name, saved / Path(name).name)
        runs = [r for r in runs if r["label"] != label] + [{k: _fmt(v) for k, v in run_.items()}]
        plans = [p for p in plans if p["label"] != label] + [{k: _fmt(v) for k, v in p.items()} for p in plans_]
        print(f"[robot_plans] {label}: " + ", ".join(f"{k} {_fmt(v)}" for k, v in run_.items()), flush=True)
        status = status or int(run_["exit"] != 0)
    for run_ in runs:  # plans.csv from each run's saved log (the log is the record; the parser may have grown)
        log = args.out / run_["label"] / "nbv_planner.log"
        if log.is_file():
            parsed, _, _ = parse_plans(log.read_text())
            plans = [p for p in plans if p["label"] != run_["label"]]
            plans += [{k: _fmt(v) for k, v in {"label": run_["label"], **p}.items()} for p in parsed]
            run_["first_checked"] = str(parsed[0]["arm_checked"]) if parsed else "0"
    write_csv(args.out / "runs.csv", RUN_COLUMNS, runs)
    write_csv(args.out / "plans.csv", PLAN_COLUMNS, plans)
    notes_path = args.out / "notes.txt"
    notes = [n for n in (notes_path.read_text().splitlines() if notes_path.is_file() else []) if n] + args.note
    notes_path.write_text("".join(n + "\n" for n in notes))
    write_summary(args.out, runs, plans, notes)
    plot(args.out, runs, plans)
    return status


def main(argv: list[str] | None = None) -> int:
    return run_command("robot_plans", HELP, add_arguments, run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
