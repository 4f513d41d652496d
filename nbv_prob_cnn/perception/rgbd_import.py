"""Write an RGB-D recording (:mod:`nbv_prob_cnn.perception.recordings`) as a depth-camera rosbag2.

The bag is the one :class:`~nbv_prob_cnn.perception.bags.BagWriter` writes (mcap storage) with
its poses on ``/tf``, as a robot's recording has them: ``/camera/depth/image`` (``16UC1``
millimetres, REP-118: 0 = no return, ``header.frame_id`` ``camera_optical``),
``/camera/depth/camera_info`` and on ``/tf`` (``tf2_msgs/TFMessage``) the one transform ``world``
-> ``camera_optical``, all three stamped as the image. ``nbv integrate --bag`` and ``nbv
gain-study`` look each pose up in TF at the image's stamp, ``bag_replay`` publishes ``/tf`` for
the ``integrator`` node's ``pose_source:=tf``, and ``launch_scripts/plan_from_bag.py`` starts the
integrator so. There is no ``/camera/pose`` (one source of truth for the poses).

The world may be turned so that a given direction becomes +z (``up``): the planner's candidate
orientations, camera heights and pictures assume a z-up world; a 7-Scenes world is the first
camera's frame, with gravity along ``gravity-direction.txt``.
"""

from __future__ import annotations

import math
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nbv_prob_cnn.perception.bags import BagWriter
from nbv_prob_cnn.perception.recordings import Recording, depth_mm, read_depth_png, up_rotation

__all__ = ["ImportSummary", "default_up", "import_recording"]


@dataclass
class ImportSummary:
    """What an import wrote and what it left out."""

    bag: Path
    listed: int  # frames of the recording with a pose
    written: int
    skipped_by_every: int
    beyond_max_frames: int
    unmatched: int  # depth images without a pose within the tolerance (TUM)
    up: np.ndarray | None
    up_angle_deg: float
    valid_fraction: float  # pixels with a return, over the written frames
    depth_max_m: float  # farthest return written
    seconds: float
    notes: list[str] = field(default_factory=list)

    def text(self) -> str:
        """The lines printed by ``nbv import-rgbd``."""
        size = sum(p.stat().st_size for p in self.bag.rglob("*") if p.is_file()) if self.bag.exists() else 0
        lines = [
            f"wrote {self.written} frame(s) to {self.bag} ({size / 1e6:.1f} MB) in {self.seconds:.1f} s",
            (
                f"frames: {self.listed} with a pose, {self.skipped_by_every} skipped by --every, "
                f"{self.beyond_max_frames} beyond --max-frames, {self.unmatched} depth image(s) without a pose "
                "(left out)"
            ),
            f"depth: {self.valid_fraction:.1%} of the pixels with a return, farthest {self.depth_max_m:.3f} m",
        ]
        if self.up is None:
            lines.append("world frame kept as recorded (no --up)")
        else:
            up = ", ".join(f"{v:.4f}" for v in self.up)
            lines.append(f"world turned by {self.up_angle_deg:.2f} deg so that ({up}) is +z")
        return "\n".join(lines + [f"note: {n}" for n in self.notes])


def default_up(recording: Recording) -> np.ndarray | None:
    """Minus the recording's gravity direction when it has one (7-Scenes' gravity-direction.txt)."""
    return None if recording.gravity is None else -recording.gravity


def import_recording(
    recording: Recording,
    out: str | Path,
    every: int = 1,
    max_frames: int | None = None,
    up: np.ndarray | tuple[float, float, float] | None = None,
    progress: bool = False,
) -> ImportSummary:
    """Write every ``every``-th frame (at most ``max_frames``) of a recording to a new bag ``out``.

    A bag left unfinished by an error is removed.

    Raises:
        ValueError: ``every`` or ``max_frames`` below 1, a bad ``up``.
        RecordingError: a depth image that cannot be read (named).
        BagError: ``out`` exists already or cannot be created.
    """
    from tqdm import tqdm

    if every < 1:
        raise ValueError(f"every: must be >= 1, got {every}")
    if max_frames is not None and max_frames < 1:
        raise ValueError(f"max_frames: must be >= 1, got {max_frames}")
    t0 = time.perf_counter()
    world_from_recording = np.eye(4) if up is None else up_rotation(up)
    angle = math.degrees(math.acos(np.clip((np.trace(world_from_recording[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
    thinned = recording.frames[::every]
    selected = thinned if max_frames is None else thinned[:max_frames]
    out = Path(out)
    valid = total = 0
    farthest = 0
    writer = BagWriter(out, pose_source="tf")
    writer.open()  # BagError when out exists: nothing of ours to remove then
    try:
        for frame in tqdm(selected, desc=f"import {recording.format}", unit="frame", disable=not progress):
            pixels = read_depth_png(frame.depth_path, recording.intrinsics)
            assert pixels is not None  # not header_only
            mm = depth_mm(recording, pixels)
            valid += int(np.count_nonzero(mm))
            total += mm.size
            farthest = max(farthest, int(mm.max(initial=0)))
            pose = world_from_recording @ frame.pose
            writer.write_frame(frame.stamp_ns, mm, recording.intrinsics, pose, encoding="16UC1")
        writer.close()
    except BaseException:
        writer.close()
        shutil.rmtree(out, ignore_errors=True)
        raise
    return ImportSummary(
        bag=out,
        listed=len(recording.frames),
        written=writer.frames,
        skipped_by_every=len(recording.frames) - len(thinned),
        beyond_max_frames=len(thinned) - len(selected),
        unmatched=recording.unmatched,
        up=None if up is None else np.asarray(up, dtype=np.float64) / np.linalg.norm(up),
        up_angle_deg=angle,
        valid_fraction=valid / total if total else 0.0,
        depth_max_m=farthest / 1000.0,
        seconds=time.perf_counter() - t0,
        notes=list(recording.notes),
    )
