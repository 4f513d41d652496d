"""Every reader of a user's path says what it was given when that is not what it takes, and which command
takes it (issue 48): ``--grid``, ``--bag``, ``--scene``, a recording's folder. Nothing is unpickled."""

from __future__ import annotations

import pickle
import re
from pathlib import Path

import numpy as np
import pytest

from nbv_prob_cnn.basics.file_kind import check_kind, sniff
from nbv_prob_cnn.cli import main
from nbv_prob_cnn.perception.bags import BagError, BagWriter, read_frames
from nbv_prob_cnn.perception.depth_camera import Intrinsics
from nbv_prob_cnn.perception.recordings import RecordingError, read_7scenes, read_recording
from nbv_prob_cnn.perception.tsdf import save_grid
from nbv_prob_cnn.worlds.world import World

ROOT = Path(__file__).resolve().parents[2]
SAMPLE_BAG = ROOT / "bags" / "3dt_seed1000_sample"


@pytest.fixture
def files(tmp_path: Path) -> dict[str, Path]:
    """One path of every kind a newcomer hands over by mistake."""
    out = {}
    out["grid"] = tmp_path / "grid.npz"
    save_grid(out["grid"], np.full((4, 4, 4), -1, np.int8), np.zeros(3), 0.1)
    out["npz"] = tmp_path / "other.npz"
    np.savez(out["npz"], a=np.zeros(2))
    out["csv"] = tmp_path / "next.csv"
    out["csv"].write_text("rank,gain,x_m\n1,0.5,0.1\n")
    out["pickle"] = tmp_path / "thing.pkl"
    out["pickle"].write_bytes(pickle.dumps({"a": 1}))
    out["png"] = tmp_path / "a.png"
    out["png"].write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(16))
    out["ply"] = tmp_path / "m.ply"
    out["ply"].write_text("ply\nformat binary_little_endian 1.0\n")
    out["octomap"] = tmp_path / "map.bt"
    out["octomap"].write_bytes(b"# Octomap OcTree binary file\nid OcTree\n")
    seven = tmp_path / "seven"
    seven.mkdir()
    (seven / "frame-000000.depth.png").write_bytes(b"\x89PNG")
    (seven / "frame-000000.pose.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    out["7scenes"] = seven
    tum = tmp_path / "tum"
    tum.mkdir()
    (tum / "depth.txt").write_text("# depth\n")
    out["tum"] = tum
    bag = tmp_path / "bag"
    with BagWriter(bag) as writer:
        writer.write_frame(1, np.full((6, 8), 1.0, np.float32), Intrinsics(8, 6, 5.0, 5.0, 3.5, 2.5), np.eye(4))
    out["bag"] = bag
    out["mcap"] = next(bag.glob("*.mcap"))
    out["world"] = tmp_path / "world.npz"
    np.savez(out["world"], ground_truth=np.zeros((2, 2, 2), np.uint8), meta=np.zeros(1, np.uint8))
    out["folder"] = tmp_path / "empty_folder"
    out["folder"].mkdir()
    return out


def test_sniff_names_each_kind(files):
    expected = {
        "grid": "grid", "npz": "npz", "csv": "csv", "pickle": "pickle", "png": "png", "ply": "ply",
        "octomap": "octomap", "7scenes": "7scenes", "tum": "tum", "bag": "bag", "mcap": "bag", "world": "world",
        "folder": "folder",
    }  # fmt: skip
    assert {name: sniff(path).kind for name, path in files.items()} == expected
    assert sniff(files["grid"].parent / "nothing_here").kind == "missing"


def test_check_kind_says_what_it_got_and_which_command_takes_it(files):
    assert check_kind(files["grid"], "--grid", ("grid",), "a grid").kind == "grid"
    says = r"--grid .*mcap is a rosbag2 bag \(mcap file\), not a grid; .*nbv integrate --bag"
    with pytest.raises(ValueError, match=says):
        check_kind(files["mcap"], "--grid", ("grid",), "a grid")
    with pytest.raises(FileNotFoundError, match="--grid .*nothing: no such file"):
        check_kind(files["grid"].parent / "nothing", "--grid", ("grid",), "a grid")


@pytest.mark.parametrize(
    ("given", "says"),
    [
        ("mcap", r"is a rosbag2 bag \(mcap file\).*goes to `nbv integrate --bag`"),
        ("bag", r"is a rosbag2 bag \(folder\).*goes to `nbv integrate --bag`"),
        ("csv", r"is a CSV table"),
        ("pickle", r"is a Python pickle \(not read"),
        ("7scenes", r"is a 7-Scenes recording.*goes to `nbv import-rgbd --format 7scenes"),
        ("world", r"is a world file.*`nbv explore --scene"),
        ("octomap", r"is an OctoMap \(\.bt/\.ot\).*goes to `nbv plan --octomap`"),
    ],
)
def test_grid_readers_name_what_they_were_given(files, given, says, tmp_path, capsys):
    for command in (["plan", "--grid", str(files[given]), "--out", str(tmp_path / "p")],
                    ["view", "--grid", str(files[given]), "--out", str(tmp_path / "v.png")]):  # fmt: skip
        assert main(command) == 2
        err = capsys.readouterr().err
        assert "--grid" in err and "allow_pickle" not in err and "unsafely" not in err
        assert len(re.findall(says, err)) == 1, err


@pytest.mark.parametrize(
    ("given", "says"),
    [
        ("7scenes", r"is a 7-Scenes recording .*goes to `nbv import-rgbd --format 7scenes SRC --out BAG`"),
        ("tum", r"is a TUM RGB-D recording .*goes to `nbv import-rgbd --format tum"),
        ("grid", r"is a grid file .*goes to `nbv plan --grid`"),
        ("csv", r"is a CSV table"),
    ],
)
def test_bag_readers_name_what_they_were_given(files, given, says, tmp_path, capsys):
    with pytest.raises(BagError, match=says):
        read_frames(files[given])
    assert main(["integrate", "--bag", str(files[given]), "--out", str(tmp_path / "g.npz")]) == 2
    assert len(re.findall(says, capsys.readouterr().err)) == 1
    assert not (tmp_path / "g.npz").exists()


def test_scene_and_recording_readers_name_what_they_were_given(files, capsys):
    with pytest.raises(ValueError, match=r"is a rosbag2 bag \(mcap file\), not a world file"):
        World.load(files["mcap"])
    with pytest.raises(ValueError, match=r"is a CSV table.*, not a world file"):
        World.load(files["csv"])
    log = str(files["grid"].parent / "x.csv")
    assert main(["explore", "--dataset", "3dt", "--scene", str(files["bag"]), "--views", "1", "--log", log]) == 2
    assert re.search(r"--scene .* is a rosbag2 bag \(folder\), not a world file", capsys.readouterr().err)
    with pytest.raises(RecordingError, match=r"SRC .* is a 7-Scenes recording .*not a TUM RGB-D recording folder"):
        read_recording("tum", files["7scenes"])
    with pytest.raises(RecordingError, match=r"SRC .* is a rosbag2 bag \(folder\), not a 7-Scenes recording folder"):
        read_recording("7scenes", files["bag"])
    with pytest.raises(RecordingError, match=r"SRC .* is a TUM RGB-D recording.*goes to `nbv import-rgbd --format tum"):
        read_recording("7scenes", files["tum"])
    with pytest.raises(RecordingError, match=r"SRC .* is a grid file"):  # the readers themselves (bench --recording)
        read_7scenes(files["grid"])
