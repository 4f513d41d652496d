"""Readers of RGB-D recordings on disk (7-Scenes, TUM RGB-D): posed 16-bit depth PNGs, no ROS.

A :class:`Recording` lists its frames (stamp, depth file, ``world_from_optical`` pose) and the
pinhole intrinsics; the depth images are read one at a time (:func:`read_depth_png`). Every
problem of the input raises :class:`RecordingError` naming the file (and the line), before a
frame is used where it can be found up front (missing files, unpaired frames, bad poses, 8-bit
or wrongly sized PNGs: only the PNG headers are read for that).

Layouts:
    * **7-Scenes** (Shotton et al. 2013; also the 3DMatch copies): ``frame-NNNNNN.depth.png``
      (16-bit, millimetres, 0 and 65535 = no return), ``frame-NNNNNN.pose.txt`` (4×4
      ``world_from_camera``, row-major, metres; camera = optical frame), optional
      ``camera-intrinsics.txt`` (3×3 ``K``; without it the published 585 / 320 / 240) and
      ``gravity-direction.txt`` (unit gravity vector in the world frame). No time stamps: frame
      ``N`` is stamped ``N / 30 s`` after :data:`SYNTHETIC_START_NS` (30 Hz capture).
    * **TUM RGB-D** (Sturm et al. 2012): ``depth.txt`` (``timestamp filename`` lines) and
      ``groundtruth.txt`` (``timestamp tx ty tz qx qy qz qw``: the optical centre in the world,
      optical frame), ``#`` comments; 16-bit depth PNGs with :data:`TUM_DEPTH_FACTOR` units per
      metre. Each depth image takes the pose of the nearest ground-truth stamp within
      ``tolerance_s`` (:data:`TUM_POSE_TOLERANCE_S`, TUM's ``associate.py`` default); the others
      are counted as unmatched and left out. Intrinsics: TUM's recommended values for the
      registered depth (525 / 319.5 / 239.5) unless given.

Poses pass :func:`~nbv_prob_cnn.perception.depth_camera.check_pose` (rotations re-orthonormalised
within its tolerance); quaternions must be unit to within the same tolerance.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nbv_prob_cnn.basics.camera import matrix_from_quaternion
from nbv_prob_cnn.basics.file_kind import check_kind, sniff
from nbv_prob_cnn.perception.depth_camera import ROTATION_TOLERANCE, Intrinsics, check_pose

__all__ = [
    "FORMATS",
    "RecordedFrame",
    "Recording",
    "RecordingError",
    "SEVEN_SCENES_INTRINSICS",
    "SYNTHETIC_START_NS",
    "TUM_DEPTH_FACTOR",
    "TUM_INTRINSICS",
    "TUM_POSE_TOLERANCE_S",
    "depth_mm",
    "read_depth_png",
    "read_recording",
    "read_7scenes",
    "read_tum",
    "up_rotation",
]

FORMATS = ("7scenes", "tum")
#: Stamp of frame 0 of a recording without time stamps (7-Scenes): 2025-01-01T00:00:00Z, as the sample bag.
SYNTHETIC_START_NS = 1_735_689_600 * 1_000_000_000
SEVEN_SCENES_RATE_HZ = 30.0
#: 7-Scenes' published (nominal) Kinect v1 depth intrinsics: ``(fx, fy, cx, cy)``.
SEVEN_SCENES_INTRINSICS = (585.0, 585.0, 320.0, 240.0)
#: TUM RGB-D's recommended intrinsics of the registered depth images (its "ROS default").
TUM_INTRINSICS = (525.0, 525.0, 319.5, 239.5)
#: TUM depth PNG units per metre.
TUM_DEPTH_FACTOR = 5000.0
#: Largest stamp difference of a TUM depth image and its ground-truth pose [s] (``associate.py``).
TUM_POSE_TOLERANCE_S = 0.02
#: 7-Scenes' original files mark "no return" with 65535 as well as 0.
SEVEN_SCENES_INVALID = 65535
DEFAULT_IMAGE_SIZE = (640, 480)

_FRAME_RE = re.compile(r"^frame-(\d+)\.depth\.png$")


class RecordingError(ValueError):
    """An RGB-D recording that cannot be read; the message names the file (and line)."""


@dataclass(frozen=True)
class RecordedFrame:
    """One posed depth image of a recording (the image stays on disk)."""

    stamp_ns: int
    depth_path: Path
    pose: np.ndarray  # float64 4x4 world_from_optical, rotation orthonormal
    pose_source: str  # "file" or "file line N": where the pose was read


@dataclass
class Recording:
    """The frames of a recording in time order, their intrinsics and how the depth is scaled."""

    source: Path
    format: str
    intrinsics: Intrinsics
    frames: list[RecordedFrame]
    depth_units_per_m: float
    invalid_values: tuple[int, ...] = ()
    gravity: np.ndarray | None = None  # unit gravity vector in the world frame, when the recording has one
    unmatched: int = 0  # depth images left out: no pose within the tolerance
    notes: list[str] = field(default_factory=list)


# ------------------------------------------------------------------------------ depth images
def read_depth_png(path: Path, intrinsics: Intrinsics | None = None, header_only: bool = False) -> np.ndarray | None:
    """The ``uint16`` pixels of a 16-bit depth PNG (``None`` with ``header_only``: only checked).

    Raises:
        RecordingError: missing or unreadable file, not a 16-bit single-channel image (an 8-bit
            PNG is named as such), or a size other than the intrinsics'.
    """
    from PIL import Image, UnidentifiedImageError

    if not path.is_file():
        raise RecordingError(f"{path}: no such depth image")
    try:
        with Image.open(path) as image:
            mode, size = image.mode, image.size
            if mode not in ("I;16", "I;16B", "I;16L", "I"):
                bits = "8-bit" if mode in ("1", "L", "P", "LA", "RGB", "RGBA") else f"mode {mode}"
                raise RecordingError(
                    f"{path}: {bits} image (PIL mode {mode}); a depth image must be a 16-bit single-channel PNG"
                )
            if intrinsics is not None and size != (intrinsics.width, intrinsics.height):
                raise RecordingError(
                    f"{path}: image is {size[0]}x{size[1]} pixels, the intrinsics are "
                    f"{intrinsics.width}x{intrinsics.height}"
                )
            if header_only:
                return None
            pixels = np.asarray(image)
    except (OSError, UnidentifiedImageError) as exc:
        raise RecordingError(f"{path}: not a readable PNG ({exc})") from exc
    if pixels.dtype != np.uint16:
        if pixels.min(initial=0) < 0 or pixels.max(initial=0) > 65535:
            raise RecordingError(f"{path}: values outside 0..65535 in a 16-bit image")
        pixels = pixels.astype(np.uint16)
    return pixels


# ---------------------------------------------------------------------------------- helpers
def _numbers(text: str, where: str, count: int) -> np.ndarray:
    try:
        values = np.array([float(v) for v in text.split()], dtype=np.float64)
    except ValueError:
        raise RecordingError(f"{where}: expected {count} numbers, got {text.strip()!r}") from None
    if values.size != count:
        raise RecordingError(f"{where}: expected {count} numbers, got {values.size}")
    if not np.all(np.isfinite(values)):
        raise RecordingError(f"{where}: NaN or infinite value in {text.strip()!r}")
    return values


def _data_lines(path: Path) -> list[tuple[int, str]]:
    """``(line number, text)`` of the non-empty, non-comment lines of a text file."""
    if not path.is_file():
        raise RecordingError(f"{path}: no such file")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise RecordingError(f"{path}: cannot read ({exc})") from exc
    return [
        (n, line) for n, line in enumerate(text.splitlines(), 1) if line.strip() and not line.lstrip().startswith("#")
    ]


def _checked_pose(matrix: np.ndarray, where: str) -> np.ndarray:
    try:
        return check_pose(matrix, where)
    except ValueError as exc:
        raise RecordingError(f"{exc}") from None


def _intrinsics(values: tuple[float, float, float, float], size: tuple[int, int], where: str) -> Intrinsics:
    fx, fy, cx, cy = (float(v) for v in values)
    width, height = (int(s) for s in size)
    try:
        intrinsics = Intrinsics(width, height, fx, fy, cx, cy)
    except ValueError as exc:
        raise RecordingError(f"{where}: {exc}") from None
    if not (0.0 <= cx < width and 0.0 <= cy < height):
        raise RecordingError(f"{where}: principal point ({cx:g}, {cy:g}) lies outside a {width}x{height} image")
    return intrinsics


def _check_images(frames: list[RecordedFrame], intrinsics: Intrinsics) -> None:
    for frame in frames:
        read_depth_png(frame.depth_path, intrinsics, header_only=True)


def up_rotation(up: np.ndarray | tuple[float, float, float]) -> np.ndarray:
    """The 4×4 rotation (smallest angle) that turns the direction ``up`` into +z.

    Raises:
        ValueError: not three finite numbers, or a zero vector.
    """
    vector = np.asarray(up, dtype=np.float64).reshape(-1)
    if vector.size != 3 or not np.all(np.isfinite(vector)) or not np.linalg.norm(vector) > 1e-9:
        raise ValueError(f"up: expected a finite non-zero 3-vector, got {vector.tolist()}")
    u = vector / np.linalg.norm(vector)
    z = np.array([0.0, 0.0, 1.0])
    cos = float(np.clip(u @ z, -1.0, 1.0))
    axis = np.cross(u, z)
    sin = float(np.linalg.norm(axis))
    rotation = np.eye(4)
    if sin < 1e-12:
        if cos < 0:  # up is -z: half a turn about x
            rotation[:3, :3] = np.diag([1.0, -1.0, -1.0])
        return rotation
    k = axis / sin
    skew = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    rotation[:3, :3] = np.eye(3) + sin * skew + (1.0 - cos) * (skew @ skew)
    return rotation


# --------------------------------------------------------------------------------- 7-Scenes
def _check_folder_kind(src: str | Path, format_name: str) -> None:
    """Refuse a path that is another kind of file or recording (a bag, a grid, the other format), naming
    what it is and the command that takes it; a bare folder is left to the reader, which names what it
    misses."""
    found = sniff(src)
    if found.kind in ("folder", "missing"):
        return
    expected = {"7scenes": "a 7-Scenes recording folder", "tum": "a TUM RGB-D recording folder"}[format_name]
    try:
        check_kind(src, "SRC", (format_name,), f"{expected} (--format {format_name})")
    except ValueError as exc:
        raise RecordingError(str(exc)) from None


def read_7scenes(
    src: str | Path,
    intrinsics: tuple[float, float, float, float] | None = None,
    image_size: tuple[int, int] = DEFAULT_IMAGE_SIZE,
) -> Recording:
    """The frames of a 7-Scenes sequence folder (see the module docstring).

    Args:
        intrinsics: ``(fx, fy, cx, cy)`` instead of ``camera-intrinsics.txt`` / the published values.
        image_size: ``(width, height)`` of every depth image.

    Raises:
        RecordingError: no such folder, no frames, a depth image without its pose file (or a pose
            without its image), an unreadable / non-finite / non-rigid pose (file and line), a bad
            intrinsics or gravity file, an 8-bit or wrongly sized PNG.
    """
    _check_folder_kind(src, "7scenes")
    root = Path(src)
    if not root.is_dir():
        raise RecordingError(f"{root}: no such folder")
    notes: list[str] = []
    if intrinsics is None:
        k_path = root / "camera-intrinsics.txt"
        if k_path.is_file():
            rows = _data_lines(k_path)
            if len(rows) != 3:
                raise RecordingError(f"{k_path}: expected 3 rows of a 3x3 matrix, got {len(rows)}")
            k = np.stack([_numbers(text, f"{k_path} line {n}", 3) for n, text in rows])
            if not np.allclose(k[2], [0.0, 0.0, 1.0]) or k[0, 1] != 0 or k[1, 0] != 0:
                raise RecordingError(f"{k_path}: not a pinhole matrix [[fx 0 cx] [0 fy cy] [0 0 1]]: {k.tolist()}")
            values = (k[0, 0], k[1, 1], k[0, 2], k[1, 2])
            where = str(k_path)
        else:
            values = SEVEN_SCENES_INTRINSICS
            where = "7-Scenes' published intrinsics"
            notes.append(f"no camera-intrinsics.txt: the published fx = fy = {values[0]:g}, c = {values[2:]}")
    else:
        values, where = intrinsics, "--intrinsics"
    k_intrinsics = _intrinsics(values, image_size, where)

    depth_files = {int(m.group(1)): p for p in root.iterdir() if (m := _FRAME_RE.match(p.name))}
    pose_files = {int(p.name[6:-9]): p for p in root.glob("frame-*.pose.txt") if p.name[6:-9].isdigit()}
    if not depth_files:
        raise RecordingError(f"{root}: no frame-NNNNNN.depth.png files (not a 7-Scenes sequence folder)")
    for number in sorted(set(depth_files) ^ set(pose_files)):
        have = depth_files.get(number) or pose_files[number]
        missing = "pose.txt" if number in depth_files else "depth.png"
        raise RecordingError(
            f"{have}: no matching frame-{number:06d}.{missing} ({len(depth_files)} depth images, "
            f"{len(pose_files)} pose files)"
        )
    frames = []
    for number in sorted(depth_files):
        path = pose_files[number]
        rows = _data_lines(path)
        if len(rows) != 4:
            raise RecordingError(f"{path}: expected 4 rows of a 4x4 matrix, got {len(rows)}")
        matrix = np.stack([_numbers(text, f"{path} line {n}", 4) for n, text in rows])
        stamp = SYNTHETIC_START_NS + round(number * 1e9 / SEVEN_SCENES_RATE_HZ)
        frames.append(RecordedFrame(stamp, depth_files[number], _checked_pose(matrix, str(path)), str(path)))

    gravity = None
    g_path = root / "gravity-direction.txt"
    if g_path.is_file():
        text = " ".join(t for _, t in _data_lines(g_path))
        gravity = _numbers(text, str(g_path), 3)
        if not np.linalg.norm(gravity) > 1e-6:
            raise RecordingError(f"{g_path}: the gravity direction is a zero vector")
        gravity = gravity / np.linalg.norm(gravity)
    _check_images(frames, k_intrinsics)
    return Recording(root, "7scenes", k_intrinsics, frames, 1000.0, (SEVEN_SCENES_INVALID,), gravity, notes=notes)


# --------------------------------------------------------------------------------------- TUM
def read_tum(
    src: str | Path,
    intrinsics: tuple[float, float, float, float] | None = None,
    image_size: tuple[int, int] = DEFAULT_IMAGE_SIZE,
    tolerance_s: float = TUM_POSE_TOLERANCE_S,
) -> Recording:
    """The frames of a TUM RGB-D sequence folder (see the module docstring).

    Raises:
        RecordingError: missing ``depth.txt`` / ``groundtruth.txt`` / a listed image, a malformed,
            non-finite or non-rigid line (file and line), stamps out of order, no matched frame,
            an 8-bit or wrongly sized PNG.
    """
    _check_folder_kind(src, "tum")
    root = Path(src)
    if not root.is_dir():
        raise RecordingError(f"{root}: no such folder")
    if not tolerance_s >= 0:
        raise RecordingError(f"tolerance: must be >= 0 s, got {tolerance_s}")
    depth_txt, truth_txt = root / "depth.txt", root / "groundtruth.txt"
    depth_rows = []
    for n, text in _data_lines(depth_txt):
        parts = text.split()
        if len(parts) != 2:
            raise RecordingError(f"{depth_txt} line {n}: expected 'timestamp filename', got {text.strip()!r}")
        stamp = _numbers(parts[0], f"{depth_txt} line {n}", 1)[0]
        depth_rows.append((stamp, root / parts[1], n))
    if not depth_rows:
        raise RecordingError(f"{depth_txt}: lists no depth image")
    truth_stamps, truth_poses, truth_lines = [], [], []
    for n, text in _data_lines(truth_txt):
        where = f"{truth_txt} line {n}"
        values = _numbers(text, where, 8)
        quat = values[4:]
        norm = float(np.linalg.norm(quat))
        if abs(norm - 1.0) > ROTATION_TOLERANCE:
            raise RecordingError(f"{where}: quaternion {quat.tolist()} has norm {norm:.6g}, not a rotation")
        pose = np.eye(4)
        pose[:3, :3] = matrix_from_quaternion(quat)
        pose[:3, 3] = values[1:4]
        truth_stamps.append(values[0])
        truth_poses.append(_checked_pose(pose, where))
        truth_lines.append(n)
    if not truth_stamps:
        raise RecordingError(f"{truth_txt}: holds no pose")
    stamps = np.asarray(truth_stamps)
    if np.any(np.diff(stamps) < 0):
        bad = int(np.argmax(np.diff(stamps) < 0)) + 1
        raise RecordingError(f"{truth_txt} line {truth_lines[bad]}: stamps out of order")
    frames, unmatched = [], 0
    for stamp, path, n in depth_rows:
        i = int(np.searchsorted(stamps, stamp))
        candidates = [j for j in (i - 1, i) if 0 <= j < len(stamps)]
        nearest = min(candidates, key=lambda j: abs(stamps[j] - stamp))
        if abs(stamps[nearest] - stamp) > tolerance_s:
            unmatched += 1
            continue
        if not path.is_file():
            raise RecordingError(f"{depth_txt} line {n}: no such depth image {path}")
        frames.append(
            RecordedFrame(round(stamp * 1e9), path, truth_poses[nearest], f"{truth_txt} line {truth_lines[nearest]}")
        )
    if not frames:
        raise RecordingError(
            f"{root}: none of the {len(depth_rows)} depth images has a ground-truth pose within ±{tolerance_s:g} s"
        )
    notes = []
    if intrinsics is None:
        intrinsics = TUM_INTRINSICS
        notes.append(f"TUM's default intrinsics fx = fy = {intrinsics[0]:g}, c = {intrinsics[2:]} (use --intrinsics)")
    k_intrinsics = _intrinsics(intrinsics, image_size, "intrinsics")
    _check_images(frames, k_intrinsics)
    return Recording(root, "tum", k_intrinsics, frames, TUM_DEPTH_FACTOR, (), None, unmatched, notes)


def read_recording(format_name: str, src: str | Path, **kwargs) -> Recording:
    """:func:`read_7scenes` or :func:`read_tum` by name (:data:`FORMATS`)."""
    readers = {"7scenes": read_7scenes, "tum": read_tum}
    if format_name not in readers:
        raise RecordingError(f"format: expected one of {FORMATS}, got {format_name!r}")
    return readers[format_name](src, **kwargs)


def depth_mm(recording: Recording, pixels: np.ndarray) -> np.ndarray:
    """A depth PNG's pixels as ``uint16`` millimetres (0 = no return; invalid markers cleared)."""
    raw = np.asarray(pixels)
    invalid = np.isin(raw, recording.invalid_values) if recording.invalid_values else np.zeros(raw.shape, bool)
    if math.isclose(recording.depth_units_per_m, 1000.0):
        mm = raw.astype(np.uint16, copy=True)
    else:
        mm = np.round(raw.astype(np.float64) * (1000.0 / recording.depth_units_per_m))
        mm = np.clip(mm, 0, 65535).astype(np.uint16)
    mm[invalid] = 0
    return mm
