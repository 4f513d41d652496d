"""Nothing silently empty (issue 48): a fusion with no return inside the box and a plan on a grid without an
empty cell say so in one line with the likely fix and exit with 3 (README, "Exit codes"); ``nbv integrate``
refuses to overwrite, as ``nbv import-rgbd`` does; ``nbv view --bag`` reads a camera bag posed by ``/tf``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nbv_prob_cnn.basics.grid import EMPTY, OCCUPIED, UNKNOWN
from nbv_prob_cnn.basics.results import EXIT_BAD_INPUT, EXIT_EMPTY, EXIT_OK, no_view_reason
from nbv_prob_cnn.cli import main
from nbv_prob_cnn.perception.bags import BagWriter, read_frames
from nbv_prob_cnn.perception.tsdf import save_grid

ROOT = Path(__file__).resolve().parents[2]
SAMPLE_BAG = ROOT / "bags" / "3dt_seed1000_sample"


@pytest.fixture(scope="module")
def tf_bag(tmp_path_factory) -> Path:
    """Six frames of the sample bag, posed on /tf as `nbv import-rgbd` writes them (no /camera/pose)."""
    path = tmp_path_factory.mktemp("tf") / "tf_bag"
    with BagWriter(path, pose_source="tf") as writer:
        for i, frame in enumerate(read_frames(SAMPLE_BAG)):
            if i == 6:
                break
            writer.write_frame(frame.stamp_ns, frame.depth_m, frame.intrinsics, frame.pose_4x4)
    return path


def test_exit_codes_are_distinct_and_documented():
    assert (EXIT_OK, EXIT_BAD_INPUT, EXIT_EMPTY) == (0, 2, 3)
    readme = (ROOT / "README.md").read_text()
    section = readme[readme.index("### Exit codes") :][:1500]
    for code in ("`0`", "`1`", "`2`", "`3`"):
        assert code in section


def test_integrate_says_when_no_return_falls_inside_the_box(tf_bag, tmp_path, capsys):
    out = tmp_path / "far.npz"
    # a box 50 m away from the scene: every frame is posed and fused, no return lands in it
    code = main(["integrate", "--bag", str(tf_bag), "--out", str(out), "--origin", "50", "50", "50",
                 "--shape", "16", "16", "16"])  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert code == EXIT_EMPTY and not out.exists()
    assert len(err) == 1 and "no return of the 6 frame(s) fell inside the --bounds box" in err[0]
    assert "--bounds auto" in err[0]


def test_integrate_refuses_to_overwrite_without_force(tf_bag, tmp_path, capsys):
    out = tmp_path / "g.npz"
    out.write_bytes(b"keep me")
    assert main(["integrate", "--bag", str(tf_bag), "--out", str(out), "--voxel", "0.04", "--shape", "37", "37",
                 "28"]) == EXIT_BAD_INPUT  # fmt: skip
    assert "--out" in capsys.readouterr().err and out.read_bytes() == b"keep me"
    mesh = tmp_path / "m.ply"
    mesh.write_bytes(b"old")
    assert main(["integrate", "--bag", str(tf_bag), "--out", str(tmp_path / "new.npz"), "--mesh", str(mesh)]) == 2
    assert "--mesh" in capsys.readouterr().err and not (tmp_path / "new.npz").exists()
    assert main(["integrate", "--bag", str(tf_bag), "--out", str(out), "--voxel", "0.04", "--shape", "37", "37",
                 "28", "--force"]) == EXIT_OK  # fmt: skip
    with np.load(out) as data:
        assert data["grid"].shape == (37, 37, 28) and (data["grid"] == OCCUPIED).any()


def test_plan_says_when_the_grid_has_no_empty_cell(tmp_path, capsys):
    grid = tmp_path / "unknown.npz"
    save_grid(grid, np.full((20, 20, 12), UNKNOWN, np.int8), np.zeros(3), 0.05)
    assert main(["plan", "--grid", str(grid), "--method", "prob_ig", "--out", str(tmp_path / "p")]) == EXIT_EMPTY
    captured = capsys.readouterr()
    (line,) = captured.err.strip().splitlines()
    assert "no empty cell to put a camera in (nothing was seen)" in line and "--bounds auto" in line
    assert "nothing unknown" not in captured.out + line and not (tmp_path / "p.csv").exists()


def test_no_view_reason_names_the_cause():
    state = np.full((6, 6, 6), UNKNOWN, np.int8)
    assert "no empty cell" in no_view_reason(state) and "nothing was seen" in no_view_reason(state)
    state[0] = OCCUPIED
    assert "only occupied cells were seen" in no_view_reason(state)
    state[:] = EMPTY
    assert "fully explored" in no_view_reason(state)
    state[0, 0, 0] = UNKNOWN
    assert "out of the sensor's range" in no_view_reason(state)


def test_view_reads_a_camera_bag_posed_by_tf(tf_bag, tmp_path, capsys):
    # the bags of `nbv import-rgbd`: /tf, image and camera_info; the planning topics are absent
    out = tmp_path / "v.png"
    assert main(["view", "--bag", str(tf_bag), "--out", str(out), "--method", "prob_ig"]) == EXIT_OK
    assert "fused 6 depth frame(s)" in capsys.readouterr().out and out.is_file()


def test_view_of_a_grid_without_an_empty_cell_says_why_its_heat_map_is_blank(tmp_path, capsys):
    grid = tmp_path / "unknown.npz"
    save_grid(grid, np.full((20, 20, 12), UNKNOWN, np.int8), np.zeros(3), 0.05)
    assert main(["view", "--grid", str(grid), "--method", "prob_ig", "--out", str(tmp_path / "v.png")]) == EXIT_OK
    out = capsys.readouterr().out
    assert "0 candidate origin(s)" in out and "note: no view with a positive gain: the grid has no empty cell" in out
