"""``nbv bench --suite scale`` (nbv_prob_cnn/bench/scale.py): the tabletop-like grids, a measured step
in a child process against the same step here, and the report."""

import numpy as np

from nbv_prob_cnn.bench.scale import (
    ScaleRow,
    _step,
    measure,
    plot_scale,
    ratio_lines,
    scale_state,
    scale_truth,
    workspace_box,
    write_scale_csv,
)
from nbv_prob_cnn.worlds import load_or_generate


def test_larger_grids_are_3dt_worlds_side_by_side_with_free_space_above():
    truth = scale_truth((130, 64, 100), 1000)
    first, second = load_or_generate("3dt", 1000).ground_truth, load_or_generate("3dt", 1001).ground_truth
    np.testing.assert_array_equal(truth[:128, :, :96], first[:, :64])
    np.testing.assert_array_equal(truth[128:, :, :96], second[:2, :64])
    assert not truth[:, :, 96:].any()


def test_workspace_box_is_centred_on_the_table():
    lo, hi = workspace_box((256, 256, 192), 0.5, 0.0116)
    assert list(lo) == [107, 107, 8] and list(hi) == [150, 150, 51]


def test_a_child_measures_the_step_this_process_takes():
    state = np.ascontiguousarray(scale_state((128, 128, 96), 1000)[:64, :64, :48])
    here = _step("today", state, None)
    child = measure("local", state)
    assert (child["cell"], child["view"]) == (here["cell"], here["view"])
    assert abs(child["gain"] - here["gain"]) <= 1e-5 * here["gain"]
    assert 0 < child["candidates"] <= here["candidates"]
    assert child["peak_rss_mb"] > 100 and child["seconds"] >= child["cnn_s"] > 0


def test_the_report_compares_paths_and_checks_the_targets(tmp_path):
    def row(grid, cells, path, seconds, rss, workspace=0.0):
        return ScaleRow(grid, cells, path, workspace, 10, seconds, seconds / 2, seconds / 2, rss, "1 2 3", 4, 0.5)

    a, b = "10×10×1", "20×20×2"
    rows = [row(a, 100, "today", 1.0, 600), row(a, 100, "local", 0.8, 500), row(b, 800, "today", 16.0, 2900),
            row(b, 800, "local", 3.3, 2100), row(b, 800, "local", 0.5, 700, 1.0)]  # fmt: skip
    lines = ratio_lines(rows, sizes=((10, 10, 1), (20, 20, 2)))
    assert lines[0] == f"{a}: local / today time 0.80, peak RSS 0.83; same best view: yes"
    assert f"local: {b} / {a} time 4.1× for 8× the cells" in lines
    assert (
        lines[-1]
        == f"targets (local path): {b} ≤ 4 s: met; {b} ≤ 2 GB: NOT met; {b} ≤ 4× {a}: NOT met; {a} ≤ 1.2 s: met"
    )
    csv = write_scale_csv(rows, tmp_path / "scale.csv").read_text().splitlines()
    assert csv[0].startswith("grid,cells,path,workspace_m") and len(csv) == 6
    assert plot_scale(rows, tmp_path / "scale.png").stat().st_size > 10_000
