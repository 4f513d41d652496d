"""The offline tools on a tiny saved grid: ``nbv plan --grid``, ``nbv view --grid`` (and on the
sample camera bag), ``nbv explore --scene`` with a grid file, ``nbv node NAME --help``."""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path

import numpy as np
import pytest

from nbv_prob_cnn.basics.camera import matrix_from_quaternion, orientations
from nbv_prob_cnn.basics.datasets import dataset_spec
from nbv_prob_cnn.basics.grid import probability_with_constant
from nbv_prob_cnn.cli import main
from nbv_prob_cnn.gain import ray_directions, view_membership
from nbv_prob_cnn.gain.reference import ray_gains_reference
from nbv_prob_cnn.perception.tsdf import save_grid

ORIGIN = (0.1, -0.2, 0.05)
RES = 0.05
REPO = Path(__file__).resolve().parents[2]


def tiny_grid() -> np.ndarray:
    """10³ cells: unknown, a seen empty room in the middle, an occupied wall at x = 7."""
    state = np.full((10, 10, 10), -1, dtype=np.int8)
    state[2:7, 2:8, 2:8] = 0
    state[7, 2:8, 2:8] = 1
    return state


@pytest.fixture()
def grid_file(tmp_path) -> Path:
    path = tmp_path / "grid.npz"
    save_grid(path, tiny_grid(), np.array(ORIGIN), RES)
    return path


def reference_view_gains(state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every empty cell and its (views,) prob_ig gains from the numpy reference, 3DU sensor
    (origin stride 1: every empty cell is a candidate)."""
    spec = dataset_spec("3du")
    dirs = ray_directions(3, spec.n_rays)
    member = view_membership(dirs, orientations(3), spec.sensor.hfov_deg, spec.sensor.vfov_deg)
    origins = np.argwhere(state == 0)
    prob = probability_with_constant(state, spec.p0)
    return origins, ray_gains_reference(state, prob, dirs, spec.sensor.r_max, origins) @ member


def read_csv(path: Path) -> tuple[list[str], list[dict]]:
    with open(path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    with open(path, newline="") as handle:
        header = next(csv.reader(handle))
    return header, rows


def test_plan_on_a_saved_grid(grid_file, tmp_path, capsys):
    out = tmp_path / "plan"
    args = ["plan", "--grid", str(grid_file), "--method", "prob_ig", "--top-k", "3", "--backend", "numpy"]
    assert main([*args, "--dataset", "3du", "--out", str(out)]) == 0
    header, rows = read_csv(out.with_suffix(".csv"))
    assert header[:2] == ["rank", "gain"] and {"x_m", "y_m", "z_m", "qx", "qy", "qz", "qw"} <= set(header)
    assert len(rows) == 3 and out.with_suffix(".png").stat().st_size > 10_000
    gains = [float(r["gain"]) for r in rows]
    assert gains == sorted(gains, reverse=True)
    origins, view_gains = reference_view_gains(tiny_grid())
    assert gains[0] == pytest.approx(float(view_gains.max()), rel=1e-4)
    for row in rows:
        cell = np.array([int(row["cell_x"]), int(row["cell_y"]), int(row["cell_z"])])
        # metres by hand: corner of cell 0 + (index + 1/2) * cell edge
        expected = [ORIGIN[i] + (cell[i] + 0.5) * RES for i in range(3)]
        assert [float(row[k]) for k in ("x_m", "y_m", "z_m")] == pytest.approx(expected, abs=1e-5)
        quat = [float(row[k]) for k in ("qx", "qy", "qz", "qw")]
        assert math.isclose(float(np.linalg.norm(quat)), 1.0, abs_tol=1e-5)
        index = int(np.flatnonzero((origins == cell).all(axis=1))[0])
        assert float(row["gain"]) == pytest.approx(float(view_gains[index, int(row["view_index"])]), rel=1e-4)
    printed = capsys.readouterr().out
    assert "#1: gain" in printed
    # 5 cm cells against the 3DU model's 1.16 cm: its 24-cell range is 24 * 0.05 = 1.20 m here
    assert "the grid's cells are 5 cm, the 3du sensor model's 1.16 cm; its range of 24 cells is 1.20 m" in printed
    closing = re.fullmatch(
        r"plan (\S+) s \(CNN (\S+) s, ray casting (\S+) s, views (\S+) s\), peak RSS (\d+) MB",
        printed.strip().splitlines()[-1],
    )
    assert closing is not None, printed.strip().splitlines()[-1]
    total, cnn, ray, views = (float(closing.group(i)) for i in range(1, 5))
    assert cnn == 0.0 and total >= ray + views - 0.02 and int(closing.group(5)) > 50  # prob_ig: no CNN


def test_plan_keeps_to_the_workspace(grid_file, tmp_path):
    out = tmp_path / "boxed"
    box = ["0.2", "0.0", "0.1", "0.3", "0.4", "0.5"]  # x in [0.2, 0.3] m: cells 2 (0.225 m) and 3 (0.275 m)
    code = main(["plan", "--grid", str(grid_file), "--method", "prob_ig", "--top-k", "5", "--backend", "numpy",
                 "--workspace", *box, "--out", str(out)])  # fmt: skip
    assert code == 0
    _, rows = read_csv(out.with_suffix(".csv"))
    assert rows and all(0.2 <= float(r["x_m"]) <= 0.3 for r in rows)
    assert {int(r["cell_x"]) for r in rows} <= {2, 3}


def test_plan_takes_the_cnn_window_and_precision(grid_file, tmp_path, monkeypatch, bf16):
    """``--cnn-window`` and ``--cnn-precision`` reach the planning context: the CNN gets the window's cells
    alone (the candidates' box grown by 1 cell, not the 10³ grid) in bfloat16."""
    import nbv_prob_cnn.completion.tiled as tiled

    calls = []
    region = tiled.complete_region
    monkeypatch.setattr(
        tiled,
        "complete_region",
        lambda state, *a, **k: calls.append((state.shape, k.get("precision"))) or region(state, *a, **k),
    )
    out = tmp_path / "windowed"
    code = main(["plan", "--grid", str(grid_file), "--method", "cnn_prob", "--dataset", "3du", "--top-k", "2",
                 "--backend", "numpy", "--cnn-window", "1", "--cnn-precision", "bfloat16",
                 "--out", str(out)])  # fmt: skip
    assert code == 0
    # the empty room's cells 2..6 x 2..7 x 2..7 grown by one cell: 7 x 8 x 8
    assert calls == [((7, 8, 8), "bfloat16")]
    assert len(read_csv(out.with_suffix(".csv"))[1]) == 2


def test_plan_refuses_what_it_cannot_do(grid_file, tmp_path, capsys):
    assert main(["plan", "--grid", str(grid_file), "--method", "prob_ig", "--workspace", "0", "1",
                 "--out", str(tmp_path / "p")]) == 2  # fmt: skip
    assert "expected 6 numbers" in capsys.readouterr().err
    world = tmp_path / "world.npz"
    assert main(["world", "--dataset", "3du", "--seed", "3", "--out", str(world)]) == 0
    assert main(["plan", "--grid", str(world), "--out", str(tmp_path / "p")]) == 2
    assert "is a world file" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # argparse: omniscient needs the ground truth, not offered
        main(["plan", "--grid", str(grid_file), "--method", "omniscient"])


def test_view_a_saved_grid(grid_file, tmp_path):
    out = tmp_path / "view.png"
    assert main(["view", "--grid", str(grid_file), "--out", str(out), "--method", "prob_ig", "--dataset", "3du",
                 "--backend", "numpy"]) == 0  # fmt: skip
    assert out.stat().st_size > 10_000
    header, rows = read_csv(out.with_suffix(".csv"))
    assert header == ["x_m", "y_m", "best_view_gain", "origins_in_column"]
    # the reference: per (x, y) column of empty cells, the best gain over its cells and views (3DU sensor)
    origins, view_gains = reference_view_gains(tiny_grid())
    best = view_gains.max(axis=1)
    expected: dict[tuple[int, int], float] = {}
    for (i, j, _), gain in zip(origins, best, strict=True):
        expected[(i, j)] = max(expected.get((i, j), 0.0), float(gain))
    assert len(rows) == len(expected) == 5 * 6
    for row in rows:
        i = round((float(row["x_m"]) - ORIGIN[0]) / RES - 0.5)
        j = round((float(row["y_m"]) - ORIGIN[1]) / RES - 0.5)
        assert float(row["best_view_gain"]) == pytest.approx(expected[(i, j)], rel=1e-4)
        assert int(row["origins_in_column"]) == 6


def test_view_the_sample_camera_bag_has_a_heat_map(tmp_path, capsys):
    bag = REPO / "bags" / "3dt_seed1000_sample"
    out = tmp_path / "bag.png"
    assert main(["view", "--bag", str(bag), "--out", str(out)]) == 0
    assert "fused 30 depth frame(s)" in capsys.readouterr().out
    _, rows = read_csv(out.with_suffix(".csv"))
    gains = np.array([float(r["best_view_gain"]) for r in rows])
    assert len(rows) > 1000 and gains.max() > 0.1  # a heat map, not an empty panel


def test_explore_says_what_a_scene_is(grid_file, tmp_path, capsys):
    assert main(["explore", "--dataset", "3dt", "--scene", str(grid_file), "--log", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err
    assert "nbv world" in err and f"nbv plan --grid {grid_file}" in err


def test_node_help_lists_parameters_without_starting(capsys):
    import rclpy

    from nbv_prob_cnn.ros.integrator import IntegratorConfig

    assert main(["node", "integrator", "--help"]) == 0
    text = capsys.readouterr().out
    assert not rclpy.ok()  # no context was initialised: the node did not start
    for name in IntegratorConfig.__dataclass_fields__:
        assert f"\n  {name} (" in text or f"\n  {name}* (" in text
    assert "voxel_size (float, default 0.0116)  [0.0001, 10]" in text
    assert 'qos_reliability (str, default "best_effort")  one of `best_effort`, `reliable`' in text
    assert "publishes  topic   /nbv/grid  [VoxelGrid]" in text
    assert main(["node", "no_such_node", "--help"]) == 2


def test_exploration_picture_names_what_it_draws(tmp_path):
    from nbv_prob_cnn.basics.geometry import GridGeometry
    from nbv_prob_cnn.viz.exploration import COLOUR_SEEN_OCCUPIED, COLOUR_UNSEEN_OCCUPIED, plot_views, state_image_2d

    state = np.full((20, 10), -1, dtype=np.int8)
    state[:5] = 0
    state[5, :5] = 1  # seen occupied
    truth = np.zeros((20, 10), dtype=np.uint8)
    truth[5, :] = 1  # the wall goes on where nobody has looked
    rgb = state_image_2d(state, truth)
    assert tuple(rgb[5, 2]) == COLOUR_SEEN_OCCUPIED and tuple(rgb[5, 8]) == COLOUR_UNSEEN_OCCUPIED
    assert COLOUR_SEEN_OCCUPIED != COLOUR_UNSEEN_OCCUPIED
    geometry = GridGeometry((2.0, -1.0, 0.0), 0.5, state.shape)
    fig = plot_views(state, [[1, 1]], [[0, 0, 0, 1]], tmp_path / "p.png", truth=truth, geometry=geometry)
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "seen occupied" in labels and "occupied, not seen (ground truth)" in labels
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x (m)", "y (m)")
    # metres: the map spans origin .. origin + 20 * 0.5 m in x, and the view sits at its cell centre
    assert ax.images[0].get_extent() == [2.0, 12.0, -1.0, 4.0]
    np.testing.assert_allclose(ax.lines[0].get_xydata()[0], [2.75, -0.25])


def test_explore_csv_names_its_units(tmp_path):
    from nbv_prob_cnn.exploration.explore import CSV_COLUMNS

    assert {"x_m", "y_m", "z_m", "time_total_s"} <= set(CSV_COLUMNS) and "x" not in CSV_COLUMNS


def test_plan_lists_a_view_once_whatever_its_roll(tmp_path):
    # issue 48: --top-k listed the same cell and viewing direction twice (rolls 0 and 90 degrees);
    # two empty cells in unknown space: many views tie, the rolls of one axis among them
    state = np.full((12, 12, 12), -1, dtype=np.int8)
    state[6, 6, 5:7] = 0
    grid = tmp_path / "two_cells.npz"
    save_grid(grid, state, np.array(ORIGIN), RES)
    out = tmp_path / "plan"
    assert main(["plan", "--grid", str(grid), "--method", "prob_ig", "--dataset", "3du", "--top-k", "8",
                 "--out", str(out), "--backend", "numpy"]) == 0  # fmt: skip
    _, rows = read_csv(out.with_suffix(".csv"))
    axes = [np.round(matrix_from_quaternion(np.array([float(r[k]) for k in ("qx", "qy", "qz", "qw")]))[:, 2], 4)
            for r in rows]  # fmt: skip
    keys = {(r["cell_x"], r["cell_y"], r["cell_z"], tuple(a)) for r, a in zip(rows, axes, strict=True)}
    assert len(rows) == 8 and len(keys) == 8
    # the reference: per (cell, viewing direction) the better of its two rolls, the 8 best of those
    origins, view_gains = reference_view_gains(state)
    per_axis = view_gains.reshape(len(origins), -1, 2).max(axis=2)  # orientations: each direction, rolls 0 and 90
    expected = np.sort(per_axis.ravel())[::-1][:8]
    np.testing.assert_allclose([float(r["gain"]) for r in rows], expected, rtol=1e-5)


def test_view_has_a_colour_bar_for_the_heights(grid_file, tmp_path, monkeypatch):
    # issue 48: the projection along z colours occupied columns by height, without a scale
    from matplotlib.figure import Figure

    figures = []
    save = Figure.savefig
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: (figures.append(fig), save(fig, *a, **k)))
    assert main(["view", "--grid", str(grid_file), "--out", str(tmp_path / "v.png"), "--method", "prob_ig",
                 "--dataset", "3du"]) == 0  # fmt: skip
    (fig,) = figures
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert "height of the highest seen occupied cell (m)" in labels
    bar = fig.axes[labels.index("height of the highest seen occupied cell (m)")]
    low, high = bar.get_ylim()  # the wall spans cells z = 2..7: its top at 7 (centre 0.05 + 7.5 * 0.05 m)
    assert high == pytest.approx(ORIGIN[2] + 7.5 * RES)


def test_view_plan_and_the_nodes_score_with_one_default_method():
    # issue 48: nbv view scored with prob_ig, nbv plan and the nodes with cnn_prob
    from nbv_prob_cnn.cli import build_parser
    from nbv_prob_cnn.planners.registry import DEFAULT_METHOD
    from nbv_prob_cnn.ros.gain_server import GainServerConfig
    from nbv_prob_cnn.ros.nbv_planner import PlannerConfig

    commands = build_parser()._subparsers._group_actions[0].choices  # type: ignore[union-attr]
    defaults = {commands["view"].get_default("method"), commands["plan"].get_default("method")}
    assert defaults | {PlannerConfig().method, GainServerConfig().method} == {DEFAULT_METHOD} == {"cnn_surface"}
