"""``nbv study arm_compare --paths`` on a tiny case (one scene, 3 views): both configurations are logged
from the same first view, the planned configuration's joint travel and counts agree with its
log, and the summary is recomputed from the run logs independently."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("pinocchio")
pytest.importorskip("ompl")

from arm_compare_runs import read, run_arm_compare, run_log  # noqa: E402

from nbv_prob_cnn.arm.robot import RobotModel  # noqa: E402
from studies.__main__ import main  # noqa: E402

SEED = 1000
VIEWS = 3
ARGS = ["--paths", "--scenes", "1", "--first-seed", str(SEED), "--views", str(VIEWS), "--stride", "16"]
ARGS += ["--free-above", "0.25", "--top-k", "1000", "--path-timeout", "0.5", "--quiet"]
CONFIGS = ("arm_lambda_0_planned", "arm_lambda_0")


@pytest.fixture(scope="module")
def compared(tmp_path_factory):
    return run_arm_compare(tmp_path_factory.mktemp("arm_compare_paths"), ARGS)


def test_both_configurations_are_logged_from_the_same_first_view(compared):
    logs = {c: run_log(compared, SEED, c) for c in CONFIGS}
    keys = ("cell_i", "cell_j", "cell_k", "view_index", "unknown_fraction", "joint_travel")
    assert logs[CONFIGS[0]][0][keys[0]] != ""
    assert {tuple(rows[0][k] for k in keys) for rows in logs.values()} == {tuple(logs[CONFIGS[0]][0][k] for k in keys)}
    assert (compared / "comparison.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_straight_moves_cost_the_straight_distance(compared):
    robot = RobotModel()
    for config in CONFIGS:
        rows = run_log(compared, SEED, config)
        qs = np.array([[float(row[f"q{j}"]) for j in range(robot.nq)] for row in rows])
        previous = np.vstack([robot.reference_q, qs[:-1]])
        for row, q, before in zip(rows, qs, previous, strict=True):
            straight = math.dist(q[robot.chain], before[robot.chain])
            if int(row["path_waypoints"]) == 2:
                assert float(row["joint_travel"]) == pytest.approx(straight, abs=1e-6)
            else:  # a planned path is at least as long as the straight line
                assert config.endswith("_planned") and float(row["joint_travel"]) >= straight - 1e-6
        for row in rows[1:]:
            if config == "arm_lambda_0":
                assert int(row["paths_planned"]) == 0 and float(row["time_path_planning_s"]) == 0.0
            assert float(row["time_path_planning_s"]) <= float(row["time_ik_collision_s"]) + 1e-9


def test_summary_is_recomputed_from_the_logs(compared):
    summary = {row["config"]: row for row in read(compared / "summary.csv")}
    assert set(summary) == set(CONFIGS)
    for config in CONFIGS:
        rows = run_log(compared, SEED, config)
        s = summary[config]
        assert float(s["feasible_iteration_fraction"]) == pytest.approx((len(rows) - 1) / (VIEWS - 1), abs=1e-4)
        assert float(s["joint_travel_total_rad_mean"]) == pytest.approx(
            sum(float(r["joint_travel"]) for r in rows), abs=1e-3
        )
        blocked = np.mean([int(r["path_blocked"]) for r in rows[1:]]) if len(rows) > 1 else math.nan
        if not math.isnan(blocked):
            assert float(s["path_blocked_per_view"]) == pytest.approx(blocked, abs=1e-3)
    table = (compared / "summary.md").read_text()
    assert all(f"| {config} |" in table for config in CONFIGS) and "path planning s/view" in table


def test_bad_path_settings_give_clear_errors(tmp_path, capsys):
    assert main(["arm_compare", "--out", str(tmp_path), "--paths", "--path-timeout", "0", "--quiet"]) == 2
    assert "timeout_s" in capsys.readouterr().err


def test_the_configurations_differ_only_from_the_first_planned_move(compared):
    """Path planning runs only where the straight path is blocked: until the first move along a
    planned path, both configurations take the same views with the same joint goals."""
    planned, straight = (run_log(compared, SEED, c) for c in CONFIGS)
    keys = ["cell_i", "cell_j", "cell_k", "view_index", "unknown_fraction", "joint_travel"]
    keys += [f"q{j}" for j in range(9)]
    for a, b in zip(planned, straight, strict=False):
        if int(a["path_waypoints"]) > 2:
            break
        assert [a[k] for k in keys] == [b[k] for k in keys]
