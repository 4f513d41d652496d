"""The OctoMap codec against OctoMap's own library (``octomap-python``, pinned in requirements.txt):
the library builds, prunes, writes and reads the trees; our streams must be its bytes, and our
grids its cells."""

from __future__ import annotations

import numpy as np
import pytest

from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.perception import octomap_codec as oc

octomap = pytest.importorskip("octomap", reason="OctoMap's Python binding (octomap-python) is not installed")

RES = 0.05


def random_grid(seed: int, shape=(24, 20, 18)) -> np.ndarray:
    """Random cells with aligned uniform blocks, so that the tree has pruned leaves of several sizes."""
    rng = np.random.default_rng(seed)
    state = rng.choice(np.array([-1, 0, 1], dtype=np.int8), size=shape, p=[0.3, 0.5, 0.2])
    state[0:8, 0:8, 0:8] = 0  # a depth-13 free leaf when the corner key is a multiple of 8
    state[8:12, 8:12, 0:4] = 1  # a depth-14 occupied leaf
    state[16:18, 0:2, 8:10] = 0  # a depth-15 free leaf
    return state


def centres(state: np.ndarray, geometry: GridGeometry) -> np.ndarray:
    return (np.argwhere(np.ones(state.shape, dtype=bool)) + 0.5) * geometry.resolution + np.asarray(geometry.origin)


def library_tree(state: np.ndarray, geometry: GridGeometry):
    """The library's tree of the grid's known cells (hits for occupied, misses for empty)."""
    tree = octomap.OcTree(geometry.resolution)
    points = centres(state, geometry)
    flat = state.reshape(-1)
    tree.updateNodes(points[flat == 1], True)
    tree.updateNodes(points[flat == 0], False)
    return tree


def library_labels(tree, state_shape, geometry: GridGeometry) -> np.ndarray:
    """-1 / 0 / 1 per cell as the library's tree says (search + isNodeOccupied at each centre)."""
    labels = tree.getLabels(centres(np.zeros(state_shape), geometry))
    return np.asarray(labels).reshape(state_shape).astype(np.int8)


def split_bt(raw: bytes) -> tuple[bytes, bytes]:
    head, _, data = raw.partition(b"data\n")
    return head, data


# ------------------------------------------------------------------------------- grid -> stream
@pytest.mark.parametrize("seed, origin", [(0, (0.0, 0.0, 0.0)), (1, (-0.4, 0.2, -0.1)), (2, (0.4, -0.8, 0.35))])
def test_our_binary_stream_is_the_librarys_bytes(seed, origin):
    state = random_grid(seed)
    geometry = GridGeometry(origin, RES, state.shape)
    stream = oc.encode_binary(state, geometry)
    tree = library_tree(state, geometry)
    head, data = split_bt(tree.writeBinary())  # writeBinary: max-likelihood values, pruned
    assert stream.data == data
    assert f"size {stream.nodes}\n".encode() in head
    assert stream.tree_id == "OcTree" and stream.binary and stream.resolution == RES


def test_our_bt_file_reads_back_in_the_library_as_the_same_cells(tmp_path):
    state = random_grid(3)
    geometry = GridGeometry((-0.4, 0.4, 0.0), RES, state.shape)  # blocks on 8-cell boundaries
    path = tmp_path / "grid.bt"
    nodes = oc.write_bt(path, state, geometry)
    tree = octomap.OcTree(RES)
    assert tree.readBinary(str(path).encode())  # False on a header / node count mismatch
    assert tree.size() == nodes
    np.testing.assert_array_equal(library_labels(tree, state.shape, geometry), state)
    # the pruned leaves: the library's tree has leaves above the deepest level
    depths = {leaf.getDepth() for leaf in tree.begin_leafs()}
    assert {13, 14, 15, 16} <= depths, depths


def test_unknown_as_occupied_fills_the_grid_and_nothing_outside(tmp_path):
    state = random_grid(4, shape=(16, 16, 16))
    geometry = GridGeometry((0.0, 0.0, 0.0), RES, state.shape)
    path = tmp_path / "conservative.bt"
    oc.write_bt(path, state, geometry, unknown_as_occupied=True)
    tree = octomap.OcTree(RES)
    assert tree.readBinary(str(path).encode())
    expected = np.where(state == -1, 1, state)
    np.testing.assert_array_equal(library_labels(tree, state.shape, geometry), expected)
    outside = GridGeometry((0.8, 0.0, 0.0), RES, state.shape)  # the next block along x: never written
    assert np.all(library_labels(tree, state.shape, outside) == -1)


def test_an_all_unknown_grid_is_the_empty_tree():
    state = np.full((4, 4, 4), -1, dtype=np.int8)
    stream = oc.encode_binary(state, GridGeometry((0.0, 0.0, 0.0), RES, state.shape))
    assert stream.data == b"" and stream.nodes == 0
    assert split_bt(octomap.OcTree(RES).writeBinary())[1] == b""
    assert len(oc.decode(stream)) == 0


# ------------------------------------------------------------------------------- stream -> grid
def multi_resolution_tree():
    """A tree written by the library with leaves at many depths: a 64-cell free cube (pruned to a
    depth-10 leaf), a 16-cell occupied cube (depth 12), 4- and 2-cell cubes (14, 15), scattered
    occupied and free cells (16)."""
    tree = octomap.OcTree(RES)
    cube = (np.argwhere(np.ones((64, 64, 64), dtype=bool)) + 0.5) * RES  # keys 32768..32831: one depth-10 node
    tree.updateNodes(cube, False)
    slab = (np.argwhere(np.ones((16, 16, 16), dtype=bool)) + 0.5) * RES + np.array([-0.8, 0.0, 0.0])
    tree.updateNodes(slab, True)
    rng = np.random.default_rng(7)
    cells = rng.integers(-40, 70, size=(600, 3))
    scattered = (cells[~np.all((cells >= 0) & (cells < 64), axis=1)][:400] + 0.5) * RES  # the cube stays whole
    tree.updateNodes(scattered[:200], True)
    tree.updateNodes(scattered[200:], False)
    block4 = (np.argwhere(np.ones((4, 4, 4), dtype=bool)) - 12 + 0.5) * RES  # after the scatter: whole
    tree.updateNodes(block4, True)
    block2 = (np.argwhere(np.ones((2, 2, 2), dtype=bool)) - 20 + 0.5) * RES
    tree.updateNodes(block2, False)
    return tree


def test_a_library_tree_with_pruned_inner_nodes_becomes_the_librarys_cells(tmp_path):
    tree = multi_resolution_tree()
    path = tmp_path / "library.bt"
    assert tree.writeBinary(str(path).encode())
    stream = oc.read_octomap_file(path)
    assert stream.binary and stream.nodes == tree.size()
    leaves = oc.decode(stream)
    assert {10, 12, 14, 15, 16} <= set(leaves.depths.tolist()), sorted(set(leaves.depths.tolist()))
    # a box that cuts through the big leaves, off the tree's centre
    box_min, box_max = np.array([-1.0, -0.35, -0.2]), np.array([3.3, 2.0, 0.45])
    state, geometry = oc.leaves_to_grid(leaves, box_min, box_max)
    assert state.shape == (86, 47, 13) and geometry.origin == pytest.approx(tuple(box_min))
    np.testing.assert_array_equal(state, library_labels(tree, state.shape, geometry))
    assert {-1, 0, 1} <= set(np.unique(state).tolist())


def test_known_bounds_are_the_librarys_metric_bounds(tmp_path):
    tree = multi_resolution_tree()
    path = tmp_path / "library.bt"
    tree.writeBinary(str(path).encode())
    low, high = oc.known_bounds(oc.decode(oc.read_octomap_file(path)))
    np.testing.assert_allclose(low, tree.getMetricMin(), atol=1e-9)
    np.testing.assert_allclose(high, tree.getMetricMax(), atol=1e-9)


def test_the_default_box_holds_every_known_cell(tmp_path):
    tree = multi_resolution_tree()
    path = tmp_path / "library.bt"
    tree.writeBinary(str(path).encode())
    leaves = oc.decode(oc.read_octomap_file(path))
    state, geometry = oc.leaves_to_grid(leaves, *oc.known_bounds(leaves))
    np.testing.assert_array_equal(state, library_labels(tree, state.shape, geometry))
    assert np.count_nonzero(state == 1) == sum(
        (leaf.getSize() / RES) ** 3 for leaf in tree.begin_leafs() if tree.isNodeOccupied(leaf)
    )


@pytest.mark.parametrize("threshold", [0.5, 0.3, 0.7, 0.95])
def test_a_full_ot_file_with_the_occupancy_threshold(tmp_path, threshold):
    """An .ot file keeps each leaf's log-odds: the threshold decides, as the library's
    setOccupancyThres does."""
    tree = octomap.OcTree(RES)
    rng = np.random.default_rng(11)
    points = (rng.integers(0, 12, size=(3000, 3)) + 0.5) * RES
    hits = rng.random(len(points)) < 0.6
    for point, hit in zip(points, hits, strict=True):  # repeated updates: many different log-odds
        tree.updateNode(point, bool(hit))
    path = tmp_path / "full.ot"
    assert tree.write(str(path).encode())
    stream = oc.read_octomap_file(path)
    assert not stream.binary
    state, geometry = oc.leaves_to_grid(oc.decode(stream, threshold), (0.0, 0.0, 0.0), (0.6, 0.6, 0.6))
    tree.setOccupancyThres(threshold)
    expected = library_labels(tree, state.shape, geometry)
    np.testing.assert_array_equal(state, expected)
    assert np.count_nonzero(expected == 1) and np.count_nonzero(expected == 0)


@pytest.mark.parametrize("threshold", [0.1, 0.5, 0.99])
def test_a_binary_trees_threshold_against_the_clamped_leaves(tmp_path, threshold):
    state = random_grid(5, shape=(8, 8, 8))
    geometry = GridGeometry((0.0, 0.0, 0.0), RES, state.shape)
    path = tmp_path / "grid.bt"
    oc.write_bt(path, state, geometry)
    tree = octomap.OcTree(RES)
    tree.readBinary(str(path).encode())
    tree.setOccupancyThres(threshold)
    ours, _ = oc.leaves_to_grid(oc.decode(oc.read_octomap_file(path), threshold), (0.0, 0.0, 0.0), (0.4, 0.4, 0.4))
    np.testing.assert_array_equal(ours, library_labels(tree, state.shape, geometry))


# ------------------------------------------------------------------------------- bad input
def library_stream() -> oc.OctreeStream:
    tree = multi_resolution_tree()
    _, data = split_bt(tree.writeBinary())
    return oc.OctreeStream("OcTree", RES, True, data)


def test_a_tree_id_other_than_octree_is_named(tmp_path):
    tree = octomap.ColorOcTree(RES)
    tree.updateNode(np.array([0.1, 0.1, 0.1]), True)
    path = tmp_path / "color.ot"
    assert tree.write(str(path).encode())
    stream = oc.read_octomap_file(path)
    with pytest.raises(oc.OctomapError, match="tree id 'ColorOcTree'"):
        oc.decode(stream)


def test_a_truncated_stream_is_named():
    stream = library_stream()
    for cut in (2, len(stream.data) // 2, len(stream.data) - 2):
        short = oc.OctreeStream("OcTree", RES, True, stream.data[:cut])
        with pytest.raises(oc.OctomapError, match="truncated binary stream"):
            oc.decode(short)
    with pytest.raises(oc.OctomapError, match="not a whole number of 2-byte nodes"):
        oc.decode(oc.OctreeStream("OcTree", RES, True, stream.data[:-1]))


def test_bytes_after_the_tree_and_impossible_trees_are_corrupt():
    stream = library_stream()
    with pytest.raises(oc.OctomapError, match="corrupt binary stream: the tree is complete"):
        oc.decode(oc.OctreeStream("OcTree", RES, True, stream.data + b"\x02\x00"))
    deep = b"\x03\x00" * 16 + b"\x02\x00"  # child 0 inner at every level: an inner node at depth 16
    with pytest.raises(oc.OctomapError, match="an OcTree has 16 levels"):
        oc.decode(oc.OctreeStream("OcTree", RES, True, deep))
    with pytest.raises(oc.OctomapError, match="inner node without children"):
        oc.decode(oc.OctreeStream("OcTree", RES, True, b"\x03\x00\x00\x00"))
    full_nan = np.array([np.nan], dtype="<f4").tobytes() + b"\x00"
    with pytest.raises(oc.OctomapError, match="no finite log-odds"):
        oc.decode(oc.OctreeStream("OcTree", RES, False, full_nan))


def test_a_file_whose_header_disagrees_with_its_stream(tmp_path):
    tree = multi_resolution_tree()
    head, data = split_bt(tree.writeBinary())
    path = tmp_path / "cut.bt"
    path.write_bytes(head + b"data\n" + data[: len(data) // 2])
    with pytest.raises(oc.OctomapError, match="truncated"):
        oc.decode(oc.read_octomap_file(path))
    wrong = head.replace(f"size {tree.size()}".encode(), f"size {tree.size() + 1}".encode())
    path.write_bytes(wrong + b"data\n" + data)
    with pytest.raises(oc.OctomapError, match=f"header says {tree.size() + 1} nodes"):
        oc.decode(oc.read_octomap_file(path))
    path.write_bytes(b"PK\x03\x04 not a tree")
    with pytest.raises(oc.OctomapError, match="not an OctoMap file"):
        oc.read_octomap_file(path)
    path.write_bytes(b"# Octomap OcTree binary file\nid OcTree\nres 0.05\n")
    with pytest.raises(oc.OctomapError, match="no 'data' line"):
        oc.read_octomap_file(path)
    with pytest.raises(FileNotFoundError, match="no such file"):
        oc.read_octomap_file(tmp_path / "missing.bt")


def test_a_box_or_grid_off_the_trees_lattice_is_named():
    leaves = oc.decode(library_stream())
    with pytest.raises(oc.OctomapError, match=r"box min \[0.013, 0.0, 0.0\] m is not on the OcTree's 0.05 m lattice"):
        oc.leaves_to_grid(leaves, (0.013, 0.0, 0.0), (1.0, 1.0, 1.0))
    with pytest.raises(oc.OctomapError, match="max must exceed min by at least one 0.05 m cell"):
        oc.leaves_to_grid(leaves, (0.0, 0.0, 0.0), (1.0, 0.0, 1.0))
    with pytest.raises(oc.OctomapError, match="beyond the OcTree"):
        oc.leaves_to_grid(leaves, (0.0, 0.0, 0.0), (2000.0, 1.0, 1.0))
    state = np.zeros((4, 4, 4), dtype=np.int8)
    with pytest.raises(oc.OctomapError, match="grid origin .* not on the OcTree's 0.05 m lattice"):
        oc.encode_binary(state, GridGeometry((0.01, 0.0, 0.0), RES, state.shape))
    with pytest.raises(oc.OctomapError, match="holds 3D grids"):
        oc.encode_binary(np.zeros((4, 4), dtype=np.int8), GridGeometry((0.0, 0.0, 0.0), RES, (4, 4)))
    with pytest.raises(oc.OctomapError, match="resolution must be a positive"):
        oc.decode(oc.OctreeStream("OcTree", 0.0, True, b""))
    with pytest.raises(oc.OctomapError, match="occupancy threshold"):
        oc.decode(library_stream(), occupancy_threshold=1.0)


def test_more_small_leaves_than_one_chunk_holds(tmp_path):
    """110 592 leaves of 2 cells a side (more than the 65 536 written to a grid at once), alternating
    free and occupied as a 3D checkerboard of 2-cell blocks."""
    blocks = np.indices((48, 48, 48)).sum(axis=0) % 2
    state = np.repeat(np.repeat(np.repeat(blocks, 2, 0), 2, 1), 2, 2).astype(np.int8)
    geometry = GridGeometry((0.0, 0.0, 0.0), RES, state.shape)
    tree = library_tree(state, geometry)
    path = tmp_path / "checker.bt"
    assert tree.writeBinary(str(path).encode())
    leaves = oc.decode(oc.read_octomap_file(path))
    assert len(leaves) == 48**3 and set(leaves.depths.tolist()) == {15}
    grid, _ = oc.leaves_to_grid(leaves, (0.0, 0.0, 0.0), (4.8, 4.8, 4.8))
    np.testing.assert_array_equal(grid, state)
