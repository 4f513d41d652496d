"""``nbv plan --octomap`` and ``nbv view --octomap`` on OctoMap files written by OctoMap's own library
(``octomap-python``): the same views as on the grid file of the same cells; the box defaults to the
known leaves' bounds; bad files and boxes are refused with the argument named."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from nbv_prob_cnn.basics.results import EXIT_BAD_INPUT
from nbv_prob_cnn.cli import main
from nbv_prob_cnn.perception.tsdf import save_grid

octomap = pytest.importorskip("octomap", reason="OctoMap's Python binding (octomap-python) is not installed")

ORIGIN = (0.1, -0.2, 0.05)  # on the 5 cm lattice
RES = 0.05
BOX = [str(v) for v in (*ORIGIN, ORIGIN[0] + 0.5, ORIGIN[1] + 0.5, ORIGIN[2] + 0.5)]


def tiny_grid() -> np.ndarray:
    """10³ cells: unknown, a seen empty room in the middle, an occupied wall at x = 7."""
    state = np.full((10, 10, 10), -1, dtype=np.int8)
    state[2:7, 2:8, 2:8] = 0
    state[7, 2:8, 2:8] = 1
    return state


@pytest.fixture()
def files(tmp_path) -> tuple[Path, Path]:
    """The tiny grid as a grid file and as a .bt the library wrote (hits for occupied, misses for empty)."""
    state = tiny_grid()
    grid = tmp_path / "grid.npz"
    save_grid(grid, state, np.array(ORIGIN), RES)
    tree = octomap.OcTree(RES)
    centres = (np.argwhere(np.ones(state.shape, dtype=bool)) + 0.5) * RES + np.array(ORIGIN)
    tree.updateNodes(centres[state.reshape(-1) == 1], True)
    tree.updateNodes(centres[state.reshape(-1) == 0], False)
    bt = tmp_path / "map.bt"
    assert tree.writeBinary(str(bt).encode())
    return grid, bt


def rows(path: Path) -> list[dict]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def test_plan_on_the_octomap_gives_the_grid_files_views(files, tmp_path):
    grid, bt = files
    common = ["--method", "prob_ig", "--top-k", "4", "--backend", "opencl", "--dataset", "3du"]
    assert main(["plan", "--grid", str(grid), *common, "--out", str(tmp_path / "from_grid")]) == 0
    assert main(["plan", "--octomap", str(bt), "--box", *BOX, *common, "--out", str(tmp_path / "from_tree")]) == 0
    expected, got = rows(tmp_path / "from_grid.csv"), rows(tmp_path / "from_tree.csv")
    assert len(got) == 4 and got == expected


def test_view_the_octomap_in_the_box_of_its_known_leaves(files, tmp_path, capsys):
    _, bt = files
    out = tmp_path / "view.png"
    assert main(["view", "--octomap", str(bt), "--out", str(out), "--method", "prob_ig", "--dataset", "3du",
                 "--backend", "numpy"]) == 0  # fmt: skip
    assert out.stat().st_size > 10_000
    heat = rows(out.with_suffix(".csv"))
    # the known cells are x 2..7, y 2..7 of the tiny grid: the default box starts at their corner, and
    # the heat map's columns are the empty cells' (x 2..6, y 2..7)
    xs = sorted({round((float(r["x_m"]) - ORIGIN[0]) / RES - 0.5) for r in heat})
    ys = sorted({round((float(r["y_m"]) - ORIGIN[1]) / RES - 0.5) for r in heat})
    assert xs == [2, 3, 4, 5, 6] and ys == [2, 3, 4, 5, 6, 7]


def test_bad_octomap_input_is_refused_naming_it(files, tmp_path, capsys):
    grid, bt = files
    base = ["plan", "--method", "prob_ig", "--backend", "numpy", "--out", str(tmp_path / "x")]
    assert main([*base, "--octomap", str(bt), "--box", "0.113", *BOX[1:]]) == EXIT_BAD_INPUT
    assert (
        f"--octomap {bt}: box min [0.113, -0.2, 0.05] m is not on the OcTree's 0.05 m lattice"
        in capsys.readouterr().err
    )
    cut = tmp_path / "cut.bt"
    raw = bt.read_bytes()
    cut.write_bytes(raw[: len(raw) - 6])
    assert main([*base, "--octomap", str(cut)]) == EXIT_BAD_INPUT
    assert f"--octomap {cut}: " in (err := capsys.readouterr().err) and "truncated" in err
    assert main([*base, "--octomap", str(grid)]) == EXIT_BAD_INPUT
    assert "is a grid file (.npz: grid, origin, resolution), not an OctoMap file" in capsys.readouterr().err
    assert main([*base, "--grid", str(bt)]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "is an OctoMap (.bt/.ot), not a grid file" in err and "an OctoMap goes to `nbv plan --octomap`" in err
    assert main([*base, "--grid", str(grid), "--box", *BOX]) == EXIT_BAD_INPUT
    assert "--box applies to --octomap only" in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()
