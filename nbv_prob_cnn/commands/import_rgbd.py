"""``nbv import-rgbd``: turn a 7-Scenes or TUM RGB-D recording into a depth-camera rosbag2 (mcap):
``/camera/depth/image`` (16UC1 mm), ``/camera/depth/camera_info`` and the poses on ``/tf`` (``world`` ->
``camera_optical``, stamped as the image; :mod:`nbv_prob_cnn.perception.rgbd_import`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

NAME = "import-rgbd"
HELP = (
    "Import an RGB-D recording (7-Scenes or TUM RGB-D layout: posed 16-bit depth PNGs) as a rosbag2 (mcap) with the "
    "depth images, camera_info and the poses on /tf, that nbv integrate, bag_replay and plan_from_bag.py read."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from nbv_prob_cnn.perception.recordings import DEFAULT_IMAGE_SIZE, FORMATS, TUM_POSE_TOLERANCE_S

    parser.add_argument("--format", required=True, choices=FORMATS, help="layout of SRC")
    parser.add_argument("src", type=Path, metavar="SRC", help="the recording's folder")
    parser.add_argument("--out", required=True, type=Path, help="the bag to write (a new rosbag2 directory)")
    parser.add_argument("--every", type=int, default=1, help="keep every N-th frame (default: %(default)s)")
    parser.add_argument("--max-frames", type=int, help="write at most this many frames (default: all)")
    parser.add_argument(
        "--up",
        nargs=3,
        type=float,
        metavar=("X", "Y", "Z"),
        help="turn the world so that this direction (in the recording's frame) is +z; default for 7scenes: minus "
        "gravity-direction.txt where present, else the frame as recorded (--up 0 0 1 keeps it)",
    )
    parser.add_argument(
        "--intrinsics",
        nargs=4,
        type=float,
        metavar=("FX", "FY", "CX", "CY"),
        help="pinhole intrinsics of the depth images (default: camera-intrinsics.txt for 7scenes, else the "
        "format's published values)",
    )
    parser.add_argument(
        "--image-size",
        nargs=2,
        type=int,
        metavar=("W", "H"),
        default=list(DEFAULT_IMAGE_SIZE),
        help="size of every depth image (default: %(default)s)",
    )
    parser.add_argument(
        "--tolerance",
        type=float,
        default=TUM_POSE_TOLERANCE_S,
        help="tum: largest stamp difference of a depth image and its ground-truth pose, s (default: %(default)s)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from nbv_prob_cnn.perception.recordings import read_recording
    from nbv_prob_cnn.perception.rgbd_import import default_up, import_recording

    if args.every < 1:
        raise ValueError(f"--every: must be >= 1, got {args.every}")
    if args.max_frames is not None and args.max_frames < 1:
        raise ValueError(f"--max-frames: must be >= 1, got {args.max_frames}")
    options = {"intrinsics": tuple(args.intrinsics) if args.intrinsics else None, "image_size": tuple(args.image_size)}
    if args.format == "tum":
        options["tolerance_s"] = args.tolerance
    recording = read_recording(args.format, args.src, **options)
    up = args.up if args.up is not None else default_up(recording)
    progress = not args.no_progress and sys.stderr.isatty()
    summary = import_recording(recording, args.out, args.every, args.max_frames, up, progress=progress)
    print(summary.text())
    return 0
