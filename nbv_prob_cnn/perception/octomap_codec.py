"""Ternary grids to and from OctoMap's ``OcTree`` streams and files (no ROS).

An ``octomap_msgs/Octomap`` message carries a tree as ``id`` (the tree class, ``"OcTree"``),
``resolution`` (the edge of a leaf at the deepest level, metres), ``binary`` and ``data``: with
``binary`` the stream of OctoMap's ``writeBinaryData`` (a ``.bt`` file's body), else the stream of
``writeData`` (an ``.ot`` file's body). Both are pre-order walks of the tree from its root:

* binary: per inner node two bytes, 2 bits per child ``i`` (bits ``2i``, ``2i+1`` of the first byte for
  children 0-3, of the second for 4-7): ``00`` unknown (no child), ``10`` free leaf (bit ``2i`` set),
  ``01`` occupied leaf, ``11`` inner node, whose own two bytes follow later in the walk;
* full: per node its log-odds (``float32``) and a byte with bit ``i`` set for each child that exists.

Child ``i`` of a node at depth ``d`` takes bit ``15 - d`` of the x, y, z keys as bits 0, 1, 2 of
``i``. A key ``k`` at depth 16 (a leaf of ``resolution``) spans ``[(k - 32768) r, (k - 32767) r)``
along its axis, so a grid cell lies on the tree's lattice when its corner is a whole multiple of
``r``. A pruned tree has leaves at any depth: a leaf at depth ``d`` covers ``2**(16 - d)`` cells a side.

OctoMap's own library reads trees only from files, and accepts a stream that ends early or goes
on after the tree (only a ``.bt`` file's header names the node count that would tell), so the
streams are walked here, with numpy, and every way a stream can be bad is an
:class:`OctomapError` that names it. The tests check these streams byte for byte against the
library (``octomap-python``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nbv_prob_cnn.basics.geometry import GridGeometry
from nbv_prob_cnn.basics.grid import EMPTY, OCCUPIED, UNKNOWN, check_state

__all__ = [
    "DEFAULT_OCCUPANCY_THRESHOLD",
    "TREE_ID",
    "OctomapError",
    "OctreeLeaves",
    "OctreeStream",
    "decode",
    "encode_binary",
    "known_bounds",
    "leaves_to_grid",
    "read_octomap_file",
    "read_octomap_grid",
    "write_bt",
]

#: The only tree class read and written here (OctoMap's occupancy tree).
TREE_ID = "OcTree"
#: OctoMap's default occupancy threshold (probability; log-odds 0): a leaf at or above it is occupied.
DEFAULT_OCCUPANCY_THRESHOLD = 0.5
#: Levels of an OcTree below its root; keys are 16-bit.
TREE_DEPTH = 16
KEY_CENTER = 1 << (TREE_DEPTH - 1)
#: The log-odds a binary stream's leaves are read with (OctoMap's default clamping thresholds,
#: probabilities 0.971 and 0.1192), against which the occupancy threshold is applied.
#: OctoMap keeps log-odds, and compares them, as ``float``.
BINARY_OCCUPIED_LOG_ODDS = np.float32(math.log(0.971 / (1 - 0.971)))
BINARY_FREE_LOG_ODDS = np.float32(math.log(0.1192 / (1 - 0.1192)))
#: A grid-to-lattice offset up to this share of a cell counts as on the lattice (float round-off).
LATTICE_TOLERANCE = 1e-4
_BINARY_HEADER = "# Octomap OcTree binary file"
_FULL_HEADER = "# Octomap OcTree file"
#: Leaves of up to 4 cells a side written to a grid at once (bounds the index arrays: 64 Ki x 64 cells).
_LEAF_CHUNK = 1 << 16
#: Offsets of child ``i`` in x, y, z (bits 0, 1, 2 of ``i``).
_CHILD_OFFSETS = np.array([[(i >> axis) & 1 for axis in range(3)] for i in range(8)], dtype=np.int64)


class OctomapError(ValueError):
    """An OctoMap stream, file or box that cannot be used; the message says why."""


@dataclass(frozen=True)
class OctreeStream:
    """A tree as a message or file carries it: class ``tree_id``, leaf edge ``resolution`` [m],
    ``binary`` (``.bt`` body) or full (``.ot`` body) stream ``data``; ``nodes``: the tree's node
    count where known (a file's header names it; a message does not)."""

    tree_id: str
    resolution: float
    binary: bool
    data: bytes
    nodes: int | None = None


@dataclass(frozen=True)
class OctreeLeaves:
    """The known leaves of a tree: ``keys`` ``(N, 3)`` int64 (the leaf's key at its own ``depths``,
    so it covers keys ``[k * 2**(16 - d), (k + 1) * 2**(16 - d))`` at depth 16), ``occupied`` (N,)
    bool, and the tree's ``resolution`` [m]."""

    keys: np.ndarray
    depths: np.ndarray
    occupied: np.ndarray
    resolution: float

    def __len__(self) -> int:
        return len(self.depths)


def _check_resolution(resolution: float, what: str) -> float:
    resolution = float(resolution)
    if not (math.isfinite(resolution) and resolution > 0):
        raise OctomapError(f"{what}: resolution must be a positive number of metres, got {resolution}")
    return resolution


def _log_odds(probability: float) -> np.float32:
    """OctoMap's ``logodds``: computed in double, kept as ``float``."""
    if not 0.0 < probability < 1.0:
        raise OctomapError(f"occupancy threshold must lie strictly between 0 and 1, got {probability}")
    return np.float32(math.log(probability / (1.0 - probability)))


# ------------------------------------------------------------------------------------------ encoding
def encode_binary(state: np.ndarray, geometry: GridGeometry, unknown_as_occupied: bool = False) -> OctreeStream:
    """A 3D ternary grid as OctoMap's binary ``OcTree`` stream (what ``writeBinaryData`` writes for
    a tree holding the grid's empty cells as free and occupied cells as occupied leaves, pruned
    as OctoMap prunes: eight equal leaves become their parent).

    Args:
        unknown_as_occupied: unknown cells of the grid go in as occupied (for collision checking:
            what was never seen may be an obstacle); else they stay out of the tree (unknown).

    Raises:
        OctomapError: not a 3D grid, or a grid OctoMap's lattice cannot hold (the corner of cell 0
            not a whole number of cells from the frame's origin, or beyond the tree's 65536 cells).
    """
    state = check_state(state)
    if state.ndim != 3:
        raise OctomapError(f"an OcTree holds 3D grids; got shape {state.shape}")
    resolution = _check_resolution(geometry.resolution, "grid")
    corner = lattice_keys(np.asarray(geometry.origin, dtype=np.float64), resolution, "grid origin")
    if np.any(corner < 0) or np.any(corner + np.asarray(state.shape) > 2 * KEY_CENTER):
        raise OctomapError(
            f"grid of {state.shape} cells at {list(geometry.origin)} m does not fit in an OcTree of "
            f"{resolution:g} m cells (keys 0..{2 * KEY_CENTER - 1}, ±{KEY_CENTER * resolution:g} m around the origin)"
        )
    known = state != UNKNOWN if not unknown_as_occupied else np.ones(state.shape, dtype=bool)
    cells = np.argwhere(known)
    keys = cells + corner
    codes = np.where(state[known] == EMPTY, 1, 2).astype(np.uint8)  # 1 free, 2 occupied (unknown -> occupied)
    records: list[tuple[int, np.ndarray, np.ndarray]] = []  # (depth of the nodes, their keys, their two bytes)
    nodes = 0
    for depth in range(TREE_DEPTH, 0, -1):  # the children at ``depth``, grouped under their parents
        if not len(keys):
            break
        parent_keys = keys >> 1
        slot = (keys & 1) @ np.array([1, 2, 4], dtype=np.int64)
        packed = (parent_keys[:, 0] << 32) | (parent_keys[:, 1] << 16) | parent_keys[:, 2]
        unique, first, inverse = np.unique(packed, return_index=True, return_inverse=True)
        fields = np.zeros((len(unique), 8), dtype=np.uint8)
        fields[inverse, slot] = codes
        nodes += len(keys)
        parent_keys = parent_keys[first]
        collapsible = np.all(fields == fields[:, :1], axis=1) & (fields[:, 0] != 3) & (depth > 1)
        inner = ~collapsible
        weights = np.array([1, 4, 16, 64], dtype=np.uint16)
        byte0 = (fields[inner, :4] * weights).sum(axis=1).astype(np.uint8)
        byte1 = (fields[inner, 4:] * weights).sum(axis=1).astype(np.uint8)
        records.append((depth - 1, parent_keys[inner], np.stack([byte0, byte1], axis=1)))
        nodes -= 8 * int(collapsible.sum())  # eight leaves became one (counted at the next level)
        keys = parent_keys
        codes = np.where(collapsible, fields[:, 0], 3).astype(np.uint8)
    if records:
        nodes += 1  # the root
    return OctreeStream(TREE_ID, resolution, True, _preorder(records), nodes)


def _preorder(records: list[tuple[int, np.ndarray, np.ndarray]]) -> bytes:
    """The records' bytes in OctoMap's pre-order: by the Morton code of the node's corner at
    depth 16 (child 0 before child 7, x the lowest bit), a node before its descendants."""
    if not records:
        return b""
    depths = np.concatenate([np.full(len(k), d, dtype=np.int64) for d, k, _ in records])
    keys = np.concatenate([k << (TREE_DEPTH - d) for d, k, _ in records])
    payload = np.concatenate([b for _, _, b in records])
    morton = np.zeros(len(keys), dtype=np.uint64)
    for bit in range(TREE_DEPTH):
        for axis in range(3):
            morton |= ((keys[:, axis] >> bit) & 1).astype(np.uint64) << np.uint64(3 * bit + axis)
    order = np.lexsort((depths, morton))
    return payload[order].tobytes()


def lattice_keys(coords: np.ndarray, resolution: float, what: str) -> np.ndarray:
    """The depth-16 keys of lattice points ``coords`` [m] (cell corners).

    Raises:
        OctomapError: a coordinate that is not a whole number of ``resolution`` cells from the frame's origin.
    """
    coords = np.asarray(coords, dtype=np.float64).reshape(-1)
    if coords.size != 3 or not np.all(np.isfinite(coords)):
        raise OctomapError(f"{what}: expected 3 finite coordinates in metres, got {coords.tolist()}")
    cells = coords / resolution
    nearest = np.round(cells)
    if np.any(np.abs(cells - nearest) > LATTICE_TOLERANCE):
        raise OctomapError(
            f"{what} {coords.tolist()} m is not on the OcTree's {resolution:g} m lattice (corners lie a whole "
            f"number of cells from the frame's origin; nearest: {(nearest * resolution).round(9).tolist()} m)"
        )
    return nearest.astype(np.int64) + KEY_CENTER


# ------------------------------------------------------------------------------------------ decoding
def _slots(byte: int, first: int, code: int | None) -> tuple[int, ...]:
    if code is None:  # a full stream's child bitset
        return tuple(i for i in range(8) if byte >> i & 1)
    return tuple(first + i for i in range(4) if (byte >> 2 * i) & 3 == code)


_INNER_LOW = [_slots(b, 0, 3) for b in range(256)]
_INNER_HIGH = [_slots(b, 4, 3) for b in range(256)]
_CHILDREN = [_slots(b, 0, None) for b in range(256)]


def _walk(kids: list[tuple[int, ...]], deepest: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    """The depth and depth-level key of each record of a pre-order stream whose record ``j`` has
    the records of children ``kids[j]`` after it (record 0: the root).

    Raises:
        OctomapError: the stream ends inside the tree, goes on after it, or nests deeper than
            ``deepest`` levels.
    """
    parents: list[int] = []
    slots: list[int] = []
    depths: list[int] = []
    stack = [(-1, 0, 0)]
    for j, children in enumerate(kids):
        if not stack:
            raise OctomapError(
                f"corrupt {what} stream: the tree is complete after {j} of its {len(kids)} records; "
                "the rest is not part of it"
            )
        parent, slot, depth = stack.pop()
        parents.append(parent)
        slots.append(slot)
        depths.append(depth)
        if children:
            if depth >= deepest:
                raise OctomapError(
                    f"corrupt {what} stream: record {j} gives children to a node at depth {depth}; "
                    f"an OcTree has {TREE_DEPTH} levels"
                )
            stack.extend((j, child, depth + 1) for child in reversed(children))
    if stack:
        raise OctomapError(
            f"truncated {what} stream: it ends after {len(kids)} records with {len(stack)} node(s) of the "
            "tree still to come"
        )
    depth_array = np.asarray(depths, dtype=np.int64)
    parent_array = np.asarray(parents, dtype=np.int64)
    slot_array = np.asarray(slots, dtype=np.int64)
    keys = np.zeros((len(kids), 3), dtype=np.int64)
    for depth in range(1, int(depth_array.max(initial=0)) + 1):  # parents are one level up, already keyed
        at = np.flatnonzero(depth_array == depth)
        keys[at] = 2 * keys[parent_array[at]] + _CHILD_OFFSETS[slot_array[at]]
    return depth_array, keys


def decode(stream: OctreeStream, occupancy_threshold: float = DEFAULT_OCCUPANCY_THRESHOLD) -> OctreeLeaves:
    """The known leaves of an ``OcTree`` stream, occupied where their occupancy is at or above
    ``occupancy_threshold`` (OctoMap's rule; a binary stream's leaves have OctoMap's clamping
    probabilities, 0.971 occupied and 0.1192 free).

    Raises:
        OctomapError: a tree class other than ``OcTree``, a bad resolution or threshold, a stream
            that is truncated or corrupt, or (from a file) a node count other than its header's.
    """
    if stream.tree_id != TREE_ID:
        raise OctomapError(
            f"tree id {stream.tree_id!r}: only {TREE_ID!r} (OctoMap's occupancy tree) can be read; publish or "
            f"save the map as an {TREE_ID}"
        )
    resolution = _check_resolution(stream.resolution, f"{TREE_ID} stream")
    threshold = _log_odds(occupancy_threshold)
    data = np.frombuffer(stream.data, dtype=np.uint8)
    if not len(data):  # a tree without a root
        leaves, nodes = _no_leaves(resolution), 0
    elif stream.binary:
        leaves, nodes = _decode_binary(data, resolution, threshold)
    else:
        leaves, nodes = _decode_full(data, resolution, threshold)
    if stream.nodes is not None and nodes != stream.nodes:
        raise OctomapError(f"corrupt {TREE_ID}: the header says {stream.nodes} nodes, the stream holds {nodes}")
    return leaves


def _no_leaves(resolution: float) -> OctreeLeaves:
    return OctreeLeaves(np.zeros((0, 3), np.int64), np.zeros(0, np.int64), np.zeros(0, bool), resolution)


def _decode_binary(data: np.ndarray, resolution: float, threshold: np.float32) -> tuple[OctreeLeaves, int]:
    if len(data) % 2:
        raise OctomapError(f"truncated binary stream: {len(data)} bytes, not a whole number of 2-byte nodes")
    pairs = data.reshape(-1, 2)
    low, high = pairs[:, 0].tolist(), pairs[:, 1].tolist()
    kids = [_INNER_LOW[a] + _INNER_HIGH[b] for a, b in zip(low, high, strict=True)]
    empty = np.flatnonzero((pairs[1:] == 0).all(axis=1))
    if len(empty):
        raise OctomapError(f"corrupt binary stream: record {int(empty[0]) + 1} is an inner node without children")
    depths, keys = _walk(kids, TREE_DEPTH - 1, "binary")
    shifts = 2 * np.arange(4, dtype=np.uint8)
    fields = np.concatenate([(pairs[:, :1] >> shifts) & 3, (pairs[:, 1:] >> shifts) & 3], axis=1)
    record, child = np.nonzero((fields == 1) | (fields == 2))
    occupied_value = np.where(fields[record, child] == 2, BINARY_OCCUPIED_LOG_ODDS, BINARY_FREE_LOG_ODDS)
    leaves = OctreeLeaves(
        2 * keys[record] + _CHILD_OFFSETS[child], depths[record] + 1, occupied_value >= threshold, resolution
    )
    return leaves, len(kids) + len(record)


def _decode_full(data: np.ndarray, resolution: float, threshold: np.float32) -> tuple[OctreeLeaves, int]:
    if len(data) % 5:
        raise OctomapError(f"truncated full stream: {len(data)} bytes, not a whole number of 5-byte nodes")
    records = data.reshape(-1, 5)
    values = np.ascontiguousarray(records[:, :4]).view("<f4").reshape(-1)
    if not np.all(np.isfinite(values)):
        bad = int(np.flatnonzero(~np.isfinite(values))[0])
        raise OctomapError(f"corrupt full stream: node {bad} has no finite log-odds")
    children = records[:, 4]
    depths, keys = _walk([_CHILDREN[c] for c in children.tolist()], TREE_DEPTH, "full")
    leaf = children == 0
    return OctreeLeaves(keys[leaf], depths[leaf], values[leaf] >= threshold, resolution), len(records)


# ------------------------------------------------------------------------------------------ grids
def known_bounds(leaves: OctreeLeaves) -> tuple[np.ndarray, np.ndarray]:
    """The axis-aligned bounds [m] of the tree's known leaves (cell corners on its lattice).

    Raises:
        OctomapError: the tree has no known leaf.
    """
    if not len(leaves):
        raise OctomapError("the OcTree has no known (free or occupied) leaf: nothing to bound; give a box")
    size = np.left_shift(1, TREE_DEPTH - leaves.depths)[:, None]
    low = (leaves.keys * size).min(axis=0)
    high = ((leaves.keys + 1) * size).max(axis=0)
    return (low - KEY_CENTER) * leaves.resolution, (high - KEY_CENTER) * leaves.resolution


def leaves_to_grid(leaves: OctreeLeaves, box_min, box_max) -> tuple[np.ndarray, GridGeometry]:
    """The ternary grid of the cells (edge: the tree's resolution) inside the box ``[box_min,
    box_max]`` [m, the tree's frame]: a free leaf's cells empty, an occupied leaf's occupied, every
    other cell unknown.

    Raises:
        OctomapError: a box corner off the tree's lattice, a box less than one cell wide, or a box
            beyond the tree's key range.
    """
    resolution = leaves.resolution
    low = lattice_keys(box_min, resolution, "box min")
    high = lattice_keys(box_max, resolution, "box max")
    shape = high - low
    if np.any(shape < 1):
        raise OctomapError(
            f"box min {np.asarray(box_min).tolist()} m to max {np.asarray(box_max).tolist()} m: max must exceed min "
            f"by at least one {resolution:g} m cell on every axis"
        )
    if np.any(low < 0) or np.any(high > 2 * KEY_CENTER):
        raise OctomapError(f"box reaches beyond the OcTree's ±{KEY_CENTER * resolution:g} m")
    state = np.full(tuple(int(n) for n in shape), UNKNOWN, dtype=np.int8)
    for depth in np.unique(leaves.depths).tolist():
        chosen = leaves.depths == depth
        size = 1 << (TREE_DEPTH - depth)
        corners = leaves.keys[chosen] * size - low
        values = np.where(leaves.occupied[chosen], OCCUPIED, EMPTY).astype(np.int8)
        inside = np.all((corners + size > 0) & (corners < shape), axis=1)
        corners, values = corners[inside], values[inside]
        if size <= 4:  # small leaves: every cell of a chunk of leaves at once (at most 4 M cells)
            offsets = np.argwhere(np.ones((size, size, size), dtype=bool))
            for start in range(0, len(corners), _LEAF_CHUNK):
                cells = (corners[start : start + _LEAF_CHUNK, None, :] + offsets[None]).reshape(-1, 3)
                repeated = np.repeat(values[start : start + _LEAF_CHUNK], len(offsets))
                keep = np.all((cells >= 0) & (cells < shape), axis=1)
                state[tuple(cells[keep].T)] = repeated[keep]
        else:
            lows = np.clip(corners, 0, shape)
            highs = np.clip(corners + size, 0, shape)
            for (x0, y0, z0), (x1, y1, z1), value in zip(lows.tolist(), highs.tolist(), values.tolist(), strict=True):
                state[x0:x1, y0:y1, z0:z1] = value
    origin = (low - KEY_CENTER) * resolution
    geometry = GridGeometry((float(origin[0]), float(origin[1]), float(origin[2])), resolution, state.shape)
    return state, geometry


# ------------------------------------------------------------------------------------------ files
def read_octomap_file(path: str | Path) -> OctreeStream:
    """The tree of an OctoMap file: ``.bt`` (binary) or ``.ot`` (full), told apart by the first line.

    Raises:
        FileNotFoundError: no such file.
        OctomapError: not an OctoMap file, or a header without ``res`` or ``data``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    raw = path.read_bytes()
    first = raw.split(b"\n", 1)[0].decode("latin-1").strip()
    if first.startswith(_BINARY_HEADER):
        binary = True
    elif first.startswith(_FULL_HEADER):
        binary = False
    else:
        raise OctomapError(
            f"{path}: not an OctoMap file (its first line is {first[:60]!r}, "
            f"not {_BINARY_HEADER!r} or {_FULL_HEADER!r})"
        )
    fields: dict[str, str] = {}
    position = len(first) + 1
    while True:
        end = raw.find(b"\n", position)
        if end < 0:
            raise OctomapError(f"{path}: the header has no 'data' line: truncated or not an OctoMap file")
        line = raw[position:end].decode("latin-1").strip()
        position = end + 1
        if line == "data":
            break
        if line and not line.startswith("#"):
            key, _, value = line.partition(" ")
            fields[key] = value.strip()
    if "res" not in fields:
        raise OctomapError(f"{path}: the header has no 'res' line (the tree's resolution)")
    try:
        resolution = float(fields["res"])
        nodes = int(fields["size"]) if "size" in fields else None
    except ValueError as exc:
        raise OctomapError(f"{path}: bad header value ({exc})") from None
    # a .bt file of OctoMap before 1.4 has no id line: it held an OcTree
    tree_id = fields.get("id", TREE_ID if binary else "")
    return OctreeStream(tree_id, resolution, binary, raw[position:], nodes)


def write_bt(path: str | Path, state: np.ndarray, geometry: GridGeometry, unknown_as_occupied: bool = False) -> int:
    """Write a 3D ternary grid as an OctoMap ``.bt`` file (header as OctoMap writes it); returns
    the tree's node count.

    Raises:
        OctomapError: what :func:`encode_binary` raises.
    """
    stream = encode_binary(state, geometry, unknown_as_occupied)
    header = (
        f"{_BINARY_HEADER}\n# (feel free to add / change comments, but leave the first line as it is!)\n#\n"
        f"id {stream.tree_id}\nsize {stream.nodes}\nres {stream.resolution!r}\ndata\n"
    )
    Path(path).write_bytes(header.encode("ascii") + stream.data)
    return int(stream.nodes or 0)


def read_octomap_grid(
    path: str | Path, box=None, occupancy_threshold: float = DEFAULT_OCCUPANCY_THRESHOLD, option: str = "--octomap"
):
    """The ternary grid of an OctoMap file (``.bt``/``.ot``) inside ``box`` (``(min, max)`` [m, the
    tree's frame], default: the bounds of the tree's known leaves), as a
    :class:`~nbv_prob_cnn.perception.saved_grid.SavedGrid`; ``option`` names the argument in errors.

    Raises:
        FileNotFoundError: no such file.
        ValueError: another kind of file (says what it is and which command takes it).
        OctomapError: not an OcTree, a truncated or corrupt one, or a box it cannot take.
    """
    from nbv_prob_cnn.basics.file_kind import check_kind
    from nbv_prob_cnn.perception.saved_grid import SavedGrid

    path = Path(path)
    check_kind(path, option, ("octomap",), "an OctoMap file (.bt or .ot)")  # a grid, a bag, ...: named
    try:
        leaves = decode(read_octomap_file(path), occupancy_threshold)
        low, high = known_bounds(leaves) if box is None else (np.asarray(box[0]), np.asarray(box[1]))
        state, geometry = leaves_to_grid(leaves, low, high)
    except OctomapError as exc:
        raise OctomapError(f"{option} {path}: {str(exc).removeprefix(f'{path}: ')}") from None
    return SavedGrid(state, geometry, path)
