"""``studies.robot_plans``: the pure parts (the planner log's plan lines, first/median, parameter
overrides, the stand-in robots' names) and the UR5e-like arm's kinematics against the UR5e's
published Denavit-Hartenberg parameters."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from studies import robot_plans
from studies.robot_plans import (
    CONFIG,
    apply_overrides,
    dominant_stage,
    parse_plans,
    plan_summary,
    read_csv,
    stand_in,
    ur5e_like_urdf,
    write_csv,
    write_summary,
)

LOG = """\
[INFO] [1796670591.27] [nbv_planner]: arm set-up for the grid (capability map, collision model): 21.9 s
[INFO] [1796670597.00] [nbv_planner]: arm check: 300 checked of 20000 candidates (673 camera-blocked skipped, 0 \
unreachable, 300 in collision, 0 path blocked; paths planned 0, not found 0); s: ik 1.00, collision 1.42, no view; \
near the camera: 1 checked of 20000 candidates (0 camera-blocked skipped, 0 unreachable, 0 in collision, 0 path \
blocked; paths planned 0, not found 0); s: ik 0.05, collision 0.38
[INFO] [1796670598.01] [nbv_planner]: view 0 (fallback: no ranked view was feasible): gain 3.6269, unknown fraction \
0.2016, 687590 cells changed; plan 8.60 s (CNN 0.90, ray casting 0.20, views 0.01, rank reply 0.31, capability 0.11, \
IK+collision 5.00 (300 checked), other 2.07), move 2.43 s, grid wait 0.62 s; servers: completion server 0.9
[WARN] [1796670600.00] [nbv_planner]: view 1: move failed (aborted: path tolerance); trying the next ranked view
[INFO] [1796670601.00] [nbv_planner]: arm check: 3 checked of 20000 candidates (0 camera-blocked skipped, 0 \
unreachable, 2 in collision, 0 path blocked; paths planned 0, not found 0); s: ik 0.05, collision 0.51
[INFO] [1796670602.96] [nbv_planner]: view 1: gain 1.5944, unknown fraction 0.1134, 138693 cells changed; plan \
2.37 s (CNN 1.00, ray casting 0.46, views 0.01, rank reply 0.35, capability 0.07, IK+collision 0.50 (1 checked), \
other 0.00), move 2.33 s, grid wait 0.25 s; servers: completion server 1.0
[INFO] [1796670607.68] [nbv_planner]: view 2: gain 0.6477, unknown fraction 0.0508, 98900 cells changed; plan 1.40 s \
(CNN 0.99, ray casting 0.38, views 0.03, other 0.00), move 1.77 s, grid wait 0.48 s
"""


def test_plan_lines_are_read_with_their_stages_fallbacks_and_failed_moves():
    plans, failed, set_up = parse_plans(LOG)
    assert [p["view"] for p in plans] == [0, 1, 2]
    assert [p["fallback"] for p in plans] == [1, 0, 0]
    assert [p["plan_s"] for p in plans] == [8.60, 2.37, 1.40]
    assert [p["checked"] for p in plans] == [300, 1, 0]  # as the plan lines say
    assert [p["arm_checked"] for p in plans] == [301, 3, 0]  # every pass of the arm check line before each
    assert [p["in_collision"] for p in plans] == [300, 2, 0]
    assert plans[0]["ik_collision_s"] == 5.00 and plans[0]["other_s"] == 2.07 and plans[0]["move_s"] == 2.43
    assert plans[2]["rank_reply_s"] == 0.0 and plans[2]["cnn_s"] == 0.99  # a plan without the arm's stages
    assert failed == 1 and set_up == 21.9
    assert parse_plans("nothing here") == ([], 0, None)


def test_first_median_and_largest_plan():
    assert plan_summary([3.0, 1.0, 2.0, 10.0]) == {"first_plan_s": 3.0, "median_plan_s": 2.5, "max_plan_s": 10.0}
    assert all(math.isnan(v) for v in plan_summary([]).values())
    plans, _, _ = parse_plans(LOG)
    assert dominant_stage(plans) == ("cnn_s", 0.99)  # medians: CNN 0.99, IK+collision 0.50, ray casting 0.38


def test_summary_from_hand_made_csvs(tmp_path):
    runs = [{"label": "a", "file": "f.yaml", "overrides": "", "speeds": "fast", "views_asked": 3, "plans": 3,
             "first_plan_s": 3.0, "median_plan_s": 2.0, "max_plan_s": 3.0, "first_checked": 300, "fallbacks": 1,
             "failed_moves": 0, "final_unknown": 0.0123,
             "arm_set_up_s": 1.5, "load_min": 1.0, "load_mean": 2.0, "load_max": 3.0, "wall_s": 60.0, "exit": 0,
             "started_utc": "2026-12-07 19:00"}]  # fmt: skip
    plans, _, _ = parse_plans(LOG)
    write_csv(tmp_path / "runs.csv", robot_plans.RUN_COLUMNS, runs)
    write_csv(tmp_path / "plans.csv", robot_plans.PLAN_COLUMNS, [{"label": "a", **p} for p in plans])
    back_runs, back_plans = read_csv(tmp_path / "runs.csv"), read_csv(tmp_path / "plans.csv")
    assert [float(p["plan_s"]) for p in back_plans] == [8.6, 2.37, 1.4]
    write_summary(tmp_path, back_runs, back_plans, ["shared the CPU with two evaluations"])
    text = (tmp_path / "summary.md").read_text()
    row = "| a | `f.yaml` | - | fast | 3 | 3.00 | 2.00 | 3.00 | 300 | 1 | 0 | 0.0123 | 1.5 | 1.0 / 2.0 / 3.0 | 0 |"
    assert row in text
    assert "cnn_s (0.99 s)" in text and "| 3 / 301 |" in text and "* shared the CPU with two evaluations" in text


def test_overrides_and_fast_speeds():
    params = yaml.safe_load((CONFIG / "panda_d435.yaml").read_text())
    out = apply_overrides(params, ["nbv_planner.min_camera_height_m=0.2", "gain_server.free_above_m=0.3"], True)
    planner = out["nbv_planner"]["ros__parameters"]
    assert planner["min_camera_height_m"] == 0.2 and out["gain_server"]["ros__parameters"]["free_above_m"] == 0.3
    assert planner["trajectory_velocity_scale"] == 1.0
    out = apply_overrides(params, ["completion_server.precision=bfloat16"], False)  # a block the file lacks
    assert out["completion_server"]["ros__parameters"] == {"precision": "bfloat16"}
    with pytest.raises(ValueError, match="NODE.NAME=VALUE"):
        apply_overrides(params, ["min_camera_height_m=0.2"], False)
    with pytest.raises(ValueError, match="NODE.NAME=VALUE"):
        apply_overrides(params, ["planner.x=1"], False)


def test_stand_ins_use_the_names_each_file_expects(tmp_path, monkeypatch):
    panda = yaml.safe_load((CONFIG / "panda_d435.yaml").read_text())
    arm, camera = stand_in(panda, tmp_path, 1000)
    assert arm["controller_action"] == "fr3_arm_controller/follow_joint_trajectory"
    assert arm["camera_frame"] == camera["camera_frame"] == "camera_depth_optical_frame"
    assert "urdf_path" not in arm and "mesh_file" not in camera  # arm_sim's Panda, sim_camera's own world
    monkeypatch.setattr(robot_plans, "shifted_scene", lambda seed, origin, path: (seed, tuple(origin)))
    ur5e = yaml.safe_load((CONFIG / "ur5e_d435.yaml").read_text())
    arm, camera = stand_in(ur5e, tmp_path, 1000)
    assert arm["controller_action"] == "scaled_joint_trajectory_controller/follow_joint_trajectory"
    assert arm["camera_parent"] == "tool0" and camera["mesh_file"] == str((1000, (0.25, -0.74, 0.70)))
    assert (tmp_path / "ur5e_like.urdf").read_text() == ur5e_like_urdf()


def _dh(a: float, alpha: float, d: float, theta: float) -> np.ndarray:
    ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
    return np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0, sa, ca, d], [0, 0, 0, 1]])


def test_the_ur5e_like_arm_has_the_ur5e_kinematics():
    """tool0 by our model against the UR5e's DH parameters (Universal Robots' published table:
    d1 0.1625, a2 -0.425, a3 -0.3922, d4 0.1333, d5 0.0997, d6 0.0996), DH base = base_link turned pi."""
    from nbv_prob_cnn.arm.robot import RobotConfig, RobotModel

    config = ur5e_like_urdf()
    params = yaml.safe_load((CONFIG / "ur5e_d435.yaml").read_text())["nbv_planner"]["ros__parameters"]
    model = RobotModel(RobotConfig(description=config, world_from_base=np.eye(4), camera_parent="tool0",
                                   parent_from_camera=np.eye(4)))  # fmt: skip
    assert model.joint_names == params["controller_joints"]
    d = [0.1625, 0, 0, 0.1333, 0.0997, 0.0996]
    a = [0, -0.425, -0.3922, 0, 0, 0]
    alpha = [math.pi / 2, 0, 0, math.pi / 2, -math.pi / 2, 0]
    rng = np.random.default_rng(0)
    for q in [np.zeros(6), *rng.uniform(-3.0, 3.0, (5, 6))]:
        expected = np.diag([-1.0, -1.0, 1.0, 1.0])
        for i in range(6):
            expected = expected @ _dh(a[i], alpha[i], d[i], q[i])
        np.testing.assert_allclose(model.camera_pose(q), expected, atol=1e-6)
    np.testing.assert_allclose(model.camera_pose(np.zeros(6))[:3, 3], [0.8172, 0.2329, 0.0628], atol=1e-4)
