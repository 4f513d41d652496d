"""``nbv_prob_cnn.ros.conversions`` without a graph: the compressed grid (issue 35, deliverable 2)
and the size limit of grids from the wire."""

from __future__ import annotations

import array
import zlib

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("nbv_prob_cnn_msgs")

from nbv_prob_cnn.basics.geometry import GridGeometry  # noqa: E402
from nbv_prob_cnn.ros.conversions import (  # noqa: E402
    MAX_GRID_CELLS,
    compress_grid_msg,
    decompress_grid_msg,
    geometry_of,
    grid_to_msg,
    msg_to_grid,
    time_msg,
)


def _grid(shape=(40, 30, 20)) -> tuple[np.ndarray, GridGeometry]:
    rng = np.random.default_rng(3)
    state = np.full(shape, -1, np.int8)
    state[:, :, :8] = 0
    state[5:20, 4:9, 2:6] = 1
    state[rng.random(shape) < 0.01] = 1  # a few lone cells: runs of every length
    return state, GridGeometry((0.5, -1.0, 0.25), 0.02, shape)


def test_compressed_grid_round_trip_keeps_everything() -> None:
    state, geometry = _grid()
    raw = grid_to_msg(state, geometry, "odom", time_msg(12_000_000_345))
    packed = compress_grid_msg(raw)
    assert packed.format == "zlib" and packed.header == raw.header and packed.origin == raw.origin
    assert (packed.size_x, packed.size_y, packed.size_z, packed.resolution) == (40, 30, 20, raw.resolution)
    # the data is one plain zlib stream of the VoxelGrid's bytes (what a C reader's uncompress() gets)
    assert zlib.decompress(bytes(packed.data)) == bytes(raw.data)
    assert len(packed.data) < len(raw.data) / 5
    back = decompress_grid_msg(packed)
    assert back == raw
    got, got_geometry = msg_to_grid(back)
    assert np.array_equal(got, state) and got_geometry == geometry


def _packed(payload: bytes, shape=(4, 3, 2), fmt="zlib"):
    raw = grid_to_msg(np.zeros(shape, np.int8), GridGeometry((0, 0, 0), 0.1, shape))
    msg = compress_grid_msg(raw)
    msg.format, msg.data = fmt, array.array("B", payload)
    return msg


@pytest.mark.parametrize(
    ("msg", "match"),
    [
        (_packed(zlib.compress(bytes(24)), fmt="zstd"), "format 'zstd' is not one of \\['zlib'\\]"),
        (_packed(b"not zlib at all"), "not a zlib stream"),
        (_packed(zlib.compress(bytes(23))), "inflates to 23 cells but size_x\\*size_y\\*size_z = 24"),
        (_packed(zlib.compress(bytes(25))), "more than size_x\\*size_y\\*size_z = 24"),
        (_packed(zlib.compress(bytes(10**6))), "more than size_x\\*size_y\\*size_z = 24"),  # a bomb is not inflated
        (_packed(zlib.compress(bytes(24))[:-4]), "truncated"),  # the stream without its checksum
    ],
)
def test_bad_compressed_grids_are_refused_with_the_reason(msg, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        decompress_grid_msg(msg)


def test_sizes_are_checked_before_anything_is_inflated() -> None:
    msg = _packed(zlib.compress(bytes(24)))
    msg.size_x, msg.size_y, msg.size_z = 2**13, 2**13, 2**2  # 2^28 cells declared
    with pytest.raises(ValueError, match="exceed the limit"):
        decompress_grid_msg(msg)


def test_grid_limit_admits_a_room_at_the_network_cell() -> None:
    # 52.6 M cells: about the 7-Scenes kitchen at 1.16 cm over its bounding box, 52.5 M (the old limit: 2^24)
    msg = grid_to_msg(np.zeros((2, 2, 2), np.int8), GridGeometry((0, 0, 0), 0.0116, (2, 2, 2)))
    msg.size_x, msg.size_y, msg.size_z = 460, 643, 178
    assert geometry_of(msg).shape == (460, 643, 178)
    msg.size_x = MAX_GRID_CELLS // (643 * 178) + 1
    with pytest.raises(ValueError, match=f"exceed the limit of {MAX_GRID_CELLS}"):
        geometry_of(msg)
