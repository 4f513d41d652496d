"""The kitchen rows of ``nbv bench --suite scale`` (nbv_prob_cnn/bench/scale_kitchen.py): the workspace
cube, the in-process fusion of the recording and the kitchen targets."""

import numpy as np
import pytest

from nbv_prob_cnn.bench.scale import ScaleRow
from nbv_prob_cnn.bench.scale_kitchen import KITCHEN, camera_box, kitchen_state, kitchen_targets


def test_the_workspace_cube_is_centred_on_the_camera_and_clipped_to_the_grid():
    # camera in cell (10, 10, 10) of 0.1 m cells: a 0.5 m cube is 5 cells, cells 8..12
    lo, hi = camera_box(np.array([1.05, 1.05, 1.05]), np.zeros(3), 0.1, 0.5, (40, 40, 40))
    assert lo.tolist() == [8, 8, 8] and hi.tolist() == [13, 13, 13]
    # near the corner of a grid whose cell 0 starts at -0.2 m: cell (1, 1, 38), clipped below and above
    lo, hi = camera_box(np.array([-0.05, -0.05, 3.65]), np.full(3, -0.2), 0.1, 0.5, (40, 40, 40))
    assert lo.tolist() == [0, 0, 36] and hi.tolist() == [4, 4, 40]
    with pytest.raises(ValueError, match="misses the grid"):
        camera_box(np.array([9.0, 0.0, 0.0]), np.zeros(3), 0.1, 0.5, (40, 40, 40))


def test_targets_are_read_on_the_kitchen_rows_only():
    def row(grid, path, workspace, seconds, rss):
        return ScaleRow(grid, 10, path, workspace, 5, seconds, 0.1, seconds - 0.1, rss, "1 2 3", 4, 0.5)

    rows = [row("256×256×192", "local", 1.5, 9.0, 9000), row("kitchen 5×5×5", "local", 0.0, 9.0, 3000),
            row("kitchen 5×5×5", "local", 1.5, 1.2, 2500), row("kitchen 5×5×5", "window", 1.5, 9.0, 9000)]  # fmt: skip
    assert kitchen_targets(rows) == (
        "targets (kitchen): 1.5 m workspace ≤ 1.5 s: local met, window NOT met; "
        "1.5 m workspace ≤ 2 GB: local NOT met, window NOT met; whole room ≤ 4 GB: met"
    )
    assert kitchen_targets(rows[:1]).endswith("whole room ≤ 4 GB: not measured")


def test_the_recording_is_fused_z_up_from_its_first_camera():
    if not KITCHEN.is_dir():
        pytest.skip(f"the shared recording is absent: {KITCHEN}")
    pytest.importorskip("open3d")
    grid, origin, first = kitchen_state(KITCHEN, voxel_m=0.08, frames=3)
    # the first camera: frame 0's pose file, turned so that minus the gravity direction is +z
    gravity = np.loadtxt(KITCHEN / "gravity-direction.txt")
    up = -gravity / np.linalg.norm(gravity)
    position = np.loadtxt(KITCHEN / "frame-000000.pose.txt")[:3, 3]
    axis = np.cross(up, [0.0, 0.0, 1.0])
    angle = np.arccos(np.clip(up[2], -1.0, 1.0))
    k = axis / np.linalg.norm(axis)
    turned = (  # Rodrigues' formula: the rotation by angle about k takes up to +z
        position * np.cos(angle) + np.cross(k, position) * np.sin(angle) + k * (k @ position) * (1 - np.cos(angle))
    )
    np.testing.assert_allclose(first, turned, atol=1e-9)
    np.testing.assert_allclose(origin / 0.08, np.round(origin / 0.08), atol=1e-9)  # a corner of the cell lattice
    occupied, empty = int(np.count_nonzero(grid == 1)), int(np.count_nonzero(grid == 0))
    assert occupied > 100 and empty > occupied, (occupied, empty)  # walls, and the free space before them
    # the observed box reaches the first camera (its rays start there), within one cell
    cell = np.floor((first - origin) / 0.08).astype(int)
    assert np.all(cell >= -1) and np.all(cell <= np.array(grid.shape)), (cell, grid.shape)
