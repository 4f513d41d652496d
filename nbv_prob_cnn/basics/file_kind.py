"""What kind of file or folder a path is, by its first bytes and its layout, and what to tell a user who
gave one kind where another is taken.

Every reader of a user's path (``--grid``, ``--bag``, ``--scene``, ``--octomap``, a recording's
folder) calls :func:`check_kind` first, so a wrong file is named for what it is (a bag, a CSV, a
7-Scenes folder, …) together with the command that takes it, instead of failing inside a parser.
Nothing here unpickles: pickles and torch checkpoints are recognised by their first bytes and never
loaded.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

__all__ = ["FileKind", "check_kind", "sniff"]

#: The commands that take each kind (the user-facing hint); kinds no command reads have none.
TAKEN_BY: dict[str, str] = {
    "grid": "`nbv plan --grid`, `nbv view --grid`",
    "world": "`nbv explore --scene`",
    "bag": "`nbv integrate --bag`, `nbv view --bag`, `plan_from_bag.py --bag`, `nbv gain-study --bag`",
    "7scenes": "`nbv import-rgbd --format 7scenes SRC --out BAG` (then `--bag BAG`)",
    "tum": "`nbv import-rgbd --format tum SRC --out BAG` (then `--bag BAG`)",
    "octomap": "`nbv plan --octomap`, `nbv view --octomap`",
}


@dataclass(frozen=True)
class FileKind:
    """``kind``: a short name (``grid``, ``world``, ``bag``, ``7scenes``, ``tum``, ``octomap``, ``npz``,
    ``npy``, ``pickle``, ``torch``, ``csv``, ``png``, ``ply``, ``xml``, ``yaml``, ``text``, ``binary``,
    ``folder``, ``empty``, ``missing``); ``what``: the same for a user (``"a rosbag2 bag (mcap file)"``)."""

    kind: str
    what: str

    @property
    def taken_by(self) -> str:
        """The commands that take this kind, or ``""``."""
        return TAKEN_BY.get(self.kind, "")


def _folder_kind(path: Path) -> FileKind:
    if (path / "metadata.yaml").is_file():
        return FileKind("bag", "a rosbag2 bag (folder)")
    if next(path.glob("frame-*.depth.png"), None) is not None:
        return FileKind("7scenes", "a 7-Scenes recording (folder of frame-NNNNNN.depth.png and .pose.txt)")
    if (path / "depth.txt").is_file():
        return FileKind("tum", "a TUM RGB-D recording (folder with depth.txt)")
    if next(path.glob("*.mcap"), None) is not None or next(path.glob("*.db3"), None) is not None:
        return FileKind("folder", "a folder of bag files without the metadata.yaml of a rosbag2 bag")
    return FileKind("folder", "a folder")


def _zip_kind(path: Path) -> FileKind:
    try:
        with zipfile.ZipFile(path) as archive:
            names = archive.namelist()
    except (zipfile.BadZipFile, OSError):
        return FileKind("binary", "a damaged zip archive")
    if any(name.endswith("data.pkl") for name in names):
        return FileKind("torch", "a torch checkpoint (network weights; not read here)")
    keys = {name[:-4] if name.endswith(".npy") else name for name in names}
    if not all(name.endswith(".npy") for name in names):
        return FileKind("binary", "a zip archive that is not a numpy .npz")
    if {"grid", "origin", "resolution"} <= keys:
        return FileKind("grid", "a grid file (.npz: grid, origin, resolution)")
    if {"ground_truth", "meta"} <= keys:
        return FileKind("world", "a world file (ground truth from `nbv world`)")
    return FileKind("npz", f"a numpy archive with keys {sorted(keys)}")


def _text_kind(head: bytes, path: Path) -> FileKind:
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError:
        return FileKind("binary", "a binary file of unknown kind")
    stripped = text.lstrip()
    if stripped.startswith("# Octomap OcTree"):
        return FileKind("octomap", "an OctoMap (.bt/.ot)")
    if stripped.startswith(("<?xml", "<robot")):
        return FileKind("xml", "an XML file (a URDF?)")
    if "rosbag2_bagfile_information" in text:
        return FileKind("yaml", "the metadata.yaml of a rosbag2 bag (give the bag's folder)")
    lines = [line for line in text.splitlines() if line.strip()][:5]
    if len(lines) >= 1 and all("," in line for line in lines):
        return FileKind("csv", "a CSV table (as nbv plan, nbv view and nbv explore --log write)")
    if path.suffix.lower() in (".yaml", ".yml"):
        return FileKind("yaml", "a YAML file")
    return FileKind("text", "a text file")


def sniff(path: str | Path) -> FileKind:
    """The kind of ``path`` by its first bytes (files) or its layout (folders); never loads a pickle."""
    path = Path(path)
    if path.is_dir():
        return _folder_kind(path)
    if not path.exists():
        return FileKind("missing", "not there")
    try:
        with open(path, "rb") as handle:
            head = handle.read(4096)
    except OSError as exc:
        return FileKind("binary", f"an unreadable file ({exc.strerror})")
    if not head:
        return FileKind("empty", "an empty file")
    if head.startswith(b"\x89MCAP"):
        return FileKind("bag", "a rosbag2 bag (mcap file)")
    if head.startswith(b"SQLite format 3\x00"):
        return FileKind("bag", "a rosbag2 bag (sqlite3 file)")
    if head.startswith((b"PK\x03\x04", b"PK\x05\x06")):
        return _zip_kind(path)
    if head.startswith(b"\x93NUMPY"):
        return FileKind("npy", "a single numpy array (.npy)")
    if head[:1] == b"\x80" and len(head) > 1 and head[1] <= 5:
        return FileKind("pickle", "a Python pickle (not read: loading a pickle can run any code)")
    if head.startswith(b"\x89PNG"):
        return FileKind("png", "a PNG image")
    if head.startswith((b"ply\n", b"ply\r\n")):
        return FileKind("ply", "a PLY mesh or point cloud (as nbv integrate --mesh/--cloud write)")
    if head.startswith(b"# Octomap OcTree"):
        return FileKind("octomap", "an OctoMap (.bt/.ot)")
    return _text_kind(head, path)


def check_kind(path: str | Path, option: str, accepted: tuple[str, ...], expected: str) -> FileKind:
    """The kind of ``path`` when it is one of ``accepted``.

    Args:
        option: the argument as the user typed it (``"--grid"``), named in the message (``""``: the path only).
        expected: what the argument takes, for a user (``"a grid file (.npz: grid, origin, resolution)"``).

    Raises:
        FileNotFoundError: no such path.
        ValueError: another kind: says what it is, what ``option`` takes and which command takes what
            was given.
    """
    path = Path(path)
    named = f"{option} {path}" if option else str(path)
    found = sniff(path)
    if found.kind == "missing":
        raise FileNotFoundError(f"{named}: no such file or folder")
    if found.kind in accepted:
        return found
    hint = f"; {found.what.split(' (')[0]} goes to {found.taken_by}" if found.taken_by else ""
    raise ValueError(f"{named} is {found.what}, not {expected}{hint}")
