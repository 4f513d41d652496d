"""What a recorded frame reveals (perception/realized_gain.py) on a hand-worked scene (issue 36).

The scene: a camera at (0.05, 0.05, 0) looking along +z at a wall 0.95 m away, through a 3 x 3 pixel
image of a 0.57 deg field of view, so only the column of 0.1 m cells around the optical axis projects
into it. Cell k of the column has its centre at z = 0.05 + 0.1 k and a signed distance 0.95 - z to the
wall. Fused (truncation 3 voxels = 0.3 m, empty margin 1.5 voxels = 0.15 m) it is observed where that
distance is at least -0.3 m (k = 0..12: 13 cells), empty where it exceeds 0.15 m (k = 0..7), occupied
for k = 8..12.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("open3d")

from nbv_prob_cnn.basics.geometry import GridGeometry  # noqa: E402
from nbv_prob_cnn.basics.grid import EMPTY, OCCUPIED, UNKNOWN  # noqa: E402
from nbv_prob_cnn.perception.bags import Frame  # noqa: E402
from nbv_prob_cnn.perception.depth_camera import Intrinsics  # noqa: E402
from nbv_prob_cnn.perception.realized_gain import (  # noqa: E402
    Fusion,
    SingleFrameObserver,
    realized_gain,
    realized_surface,
    recording_box,
)

PINHOLE = Intrinsics(3, 3, 300.0, 300.0, 1.0, 1.0)
FUSION = Fusion(0.1, depth_max_m=3.0)
BOX = GridGeometry((-0.2, -0.2, 0.0), 0.1, (4, 4, 20))  # the camera's column is x = y = 2


def wall_frame(x: float = 0.05, depth: float = 0.95) -> Frame:
    pose = np.eye(4)
    pose[:3, 3] = [x, 0.05, 0.0]
    return Frame(0, np.full((3, 3), depth, dtype=np.float32), PINHOLE, pose)


def test_a_single_frame_observes_the_column_to_the_truncation_band():
    observed = SingleFrameObserver(BOX, FUSION).observed(wall_frame())
    expected = np.zeros(BOX.shape, dtype=bool)
    expected[2, 2, 0:13] = True
    np.testing.assert_array_equal(observed, expected)
    # the labels behind it: empty to k = 7, occupied k = 8..12
    grid = FUSION.integrator(BOX)
    FUSION.fuse(grid, wall_frame())
    np.testing.assert_array_equal(grid.ternary()[2, 2], [EMPTY] * 8 + [OCCUPIED] * 5 + [UNKNOWN] * 7)


def test_the_realized_gain_counts_the_observed_cells_the_anchor_did_not_know():
    observer = SingleFrameObserver(BOX, FUSION)
    anchor = np.full(BOX.shape, UNKNOWN, dtype=np.int8)
    anchor[2, 2, 0:5] = EMPTY  # the first five cells of the column known already
    anchor[2, 2, 9] = OCCUPIED  # and one in the band
    anchor[0, 0, :] = EMPTY  # known cells the frame does not see change nothing
    # observed k = 0..12, unknown at the anchor: k = 5..8 and 10..12
    assert realized_gain(anchor, observer.observed(wall_frame())) == 7
    # a frame with no return observes nothing; the observer starts afresh for every frame
    assert realized_gain(anchor, observer.observed(wall_frame(depth=0.0))) == 0
    assert realized_gain(anchor, observer.observed(wall_frame())) == 7
    with pytest.raises(ValueError, match="observed"):
        realized_gain(anchor, np.zeros((4, 4, 19), dtype=bool))


def test_the_realized_surface_counts_the_cells_seen_occupied_the_anchor_did_not_know():
    observer = SingleFrameObserver(BOX, FUSION)
    anchor = np.full(BOX.shape, UNKNOWN, dtype=np.int8)
    anchor[2, 2, 0:5] = EMPTY
    anchor[2, 2, 9] = OCCUPIED  # a surface cell seen before
    # the frame sees k = 8..12 occupied; unknown at the anchor among them: 8, 10, 11, 12
    assert realized_surface(anchor, observer.labels(wall_frame())) == 4
    assert realized_surface(anchor, observer.labels(wall_frame(depth=0.0))) == 0
    with pytest.raises(ValueError, match="labels"):
        realized_surface(anchor, np.zeros((4, 4, 19), dtype=np.int8))


def test_the_recording_box_holds_what_is_observed_and_every_camera():
    # the column alone: on the lattice of the world origin, cells (0, 0, 0..12)
    box = recording_box([wall_frame()], FUSION)
    assert box.origin == pytest.approx((0.0, 0.0, 0.0)) and box.shape == (1, 1, 13) and box.resolution == 0.1
    # a second camera, at x = -0.25 (cell -3), that sees nothing: the box grows to hold its cell
    box = recording_box([wall_frame(), wall_frame(x=-0.25, depth=0.0)], FUSION)
    assert box.origin == pytest.approx((-0.3, 0.0, 0.0)) and box.shape == (4, 1, 13)
    with pytest.raises(ValueError, match="no frame observes"):
        recording_box([wall_frame(depth=0.0)], FUSION)
    with pytest.raises(ValueError, match="no frame"):
        recording_box([], FUSION)


@pytest.mark.parametrize(("voxel", "depth_max", "match"), [(0.0, 3.0, "voxel"), (0.1, -1.0, "depth_max")])
def test_bad_fusion_settings_are_refused_by_name(voxel, depth_max, match):
    with pytest.raises(ValueError, match=match):
        Fusion(voxel, depth_max)
