"""``nbv study arm_compare`` on a tiny case: the logs are checked against independent recomputations
(joint travel from the logged configurations, forward kinematics of the logged joint goals, the
unknown fraction by replaying the logged views), and a re-run resumes without redoing runs."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("pinocchio")

from arm_compare_runs import read, run_arm_compare, run_log  # noqa: E402

from nbv_prob_cnn.arm.ik import DEFAULT_IK  # noqa: E402
from nbv_prob_cnn.arm.kinematics import CameraChain  # noqa: E402
from nbv_prob_cnn.arm.robot import RobotModel  # noqa: E402
from nbv_prob_cnn.basics.camera import matrix_from_quaternion  # noqa: E402
from studies.__main__ import main  # noqa: E402
from studies.arm_comparison import STAGE_COUNTS  # noqa: E402

SEED = 1000
VIEWS = 3
ARGS = ["--scenes", "1", "--first-seed", str(SEED), "--views", str(VIEWS), "--stride", "16"]
ARGS += ["--free-above", "0.25", "--top-k", "1000", "--motion-weight", "0.1", "--quiet"]
CONFIGS = ("free_flying", "arm_lambda_0", "arm_lambda_0.1")


@pytest.fixture(scope="module")
def compared(tmp_path_factory):
    return run_arm_compare(tmp_path_factory.mktemp("arm_compare"), ARGS)


def test_outputs_are_written(compared):
    for config in CONFIGS:
        assert (compared / "runs" / f"seed{SEED}_{config}.csv").is_file()
    for name in ("summary.csv", "summary.md", "comparison.png"):
        assert (compared / name).stat().st_size > 0
    assert (compared / "comparison.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_all_configurations_share_the_first_view(compared):
    firsts = [run_log(compared, SEED, c)[0] for c in CONFIGS]
    keys = ("cell_i", "cell_j", "cell_k", "view_index", "unknown_fraction")
    assert all(tuple(f[k] for k in keys) == tuple(firsts[0][k] for k in keys) for f in firsts)


def test_free_flying_log_has_no_joint_columns(compared):
    rows = run_log(compared, SEED, "free_flying")
    assert len(rows) == VIEWS
    assert all(row["joint_travel"] == "" and row["time_ik_collision_s"] == "" for row in rows)
    assert all(float(row["time_gain_s"]) > 0 for row in rows[1:])


@pytest.mark.parametrize("config", CONFIGS[1:])
def test_arm_log_is_consistent_with_kinematics(compared, config):
    robot = RobotModel()
    chain = CameraChain(robot)
    rows = run_log(compared, SEED, config)
    assert len(rows) >= 2, "the arm took no planned view on the tiny case"
    qs = np.array([[float(row[f"q{j}"]) for j in range(robot.nq)] for row in rows])
    previous = np.vstack([robot.reference_q, qs[:-1]])
    for row, q, before in zip(rows, qs, previous, strict=True):
        # joint travel: the straight joint path from the previous configuration, recomputed
        expected = math.sqrt(sum((q[j] - before[j]) ** 2 for j in chain.q_index))
        assert float(row["joint_travel"]) == pytest.approx(expected, abs=1e-6)
        # the joint goal reproduces the logged view pose by forward kinematics
        pose = robot.camera_pose(q)
        position = np.array([float(row[k]) for k in ("x", "y", "z")])
        rotation = matrix_from_quaternion(np.array([float(row[k]) for k in ("qx", "qy", "qz", "qw")]))
        assert np.linalg.norm(pose[:3, 3] - position) < DEFAULT_IK.position_tol + 1e-5
        cos = (np.trace(pose[:3, :3].T @ rotation) - 1.0) / 2.0
        assert math.acos(min(1.0, max(-1.0, cos))) < DEFAULT_IK.rotation_tol + 1e-4
        assert np.all(q >= robot.lower - 1e-9) and np.all(q <= robot.upper + 1e-9)
    for row in rows[1:]:
        times = [float(row[k]) for k in ("time_gain_s", "time_capability_s", "time_ik_collision_s")]
        assert all(t >= 0 for t in times) and sum(times) <= float(row["time_total_s"]) + 1e-6
        # candidates per stage: each stage keeps at most what the one before handed it, and
        # every exact check but the accepted ones ends in exactly one of the three failures
        n = {k: int(row[k]) for k in STAGE_COUNTS}
        assert n["candidates"] <= n["ranked"] and n["camera_blocked"] + n["checked"] <= n["candidates"]
        failures = n["unreachable"] + n["in_collision"] + n["path_blocked"]
        if config == "arm_lambda_0":
            assert failures == n["checked"] - 1  # λ = 0: the first feasible view ends the check
        else:
            assert failures <= n["checked"] - 1
        assert n["fallback"] in (0, 1)


@pytest.mark.parametrize("config", CONFIGS)
def test_unknown_fraction_replays(compared, config):
    from nbv_prob_cnn.basics.grid import unknown_fraction
    from nbv_prob_cnn.planners import PlanningContext
    from nbv_prob_cnn.sensing.observe import observe
    from nbv_prob_cnn.worlds import load_or_generate

    world = load_or_generate("3dt", SEED)
    context = PlanningContext.for_dataset("3dt")
    geometry = world.geometry
    state = np.full(world.shape, -1, dtype=np.int8)
    for row in run_log(compared, SEED, config):
        cell = np.array([int(row[k]) for k in ("cell_i", "cell_j", "cell_k")])
        np.testing.assert_allclose(geometry.cell_centre(cell), [float(row[k]) for k in ("x", "y", "z")], atol=1e-6)
        observe(state, world.ground_truth, cell, context.orientations[int(row["view_index"])], context.active_sensor)
        assert float(row["unknown_fraction"]) == pytest.approx(unknown_fraction(state, world.ground_truth), abs=1e-6)


def test_summary_matches_the_run_logs(compared):
    summary = {row["config"]: row for row in read(compared / "summary.csv")}
    assert set(summary) == set(CONFIGS)
    for config in CONFIGS:
        rows = run_log(compared, SEED, config)
        assert float(summary[config]["unknown_fraction_final_mean"]) == pytest.approx(
            float(rows[-1]["unknown_fraction"]), abs=1e-6
        )
        assert int(summary[config]["runs_complete"]) == int(len(rows) == VIEWS)
        if config != "free_flying":
            travel = sum(float(row["joint_travel"]) for row in rows)
            assert float(summary[config]["joint_travel_total_mean"]) == pytest.approx(travel, abs=1e-5)
            checked = np.mean([int(row["checked"]) for row in rows[1:]])
            assert float(summary[config]["checked_per_view_mean"]) == pytest.approx(checked, abs=1e-3)
            fallback = sum(int(row["fallback"]) for row in rows[1:])
            assert float(summary[config]["fallback_views_per_run_mean"]) == pytest.approx(fallback, abs=1e-3)
        else:
            assert summary[config]["checked_per_view_mean"] == ""
    assert summary["free_flying"]["joint_travel_total_mean"] == ""
    table = (compared / "summary.md").read_text()
    assert all(f"| {config} |" in table for config in CONFIGS)


def test_rerun_skips_finished_runs(compared):
    runs = sorted((compared / "runs").glob("*.csv"))
    stamps = {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in runs}
    before = (compared / "summary.csv").read_text()
    run_arm_compare(compared, ARGS)
    assert {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in runs} == stamps
    assert (compared / "summary.csv").read_text() == before


def test_bad_arguments_give_clear_errors(tmp_path, capsys):
    assert main(["arm_compare", "--out", str(tmp_path), "--motion-weight", "0", "--quiet"]) == 2
    assert "--motion-weight" in capsys.readouterr().err
    assert main(["arm_compare", "--out", str(tmp_path), "--method", "nope", "--quiet"]) == 2
    assert "--method" in capsys.readouterr().err
