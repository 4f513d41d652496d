"""``nbv gain-study`` end to end on a bag the test writes (a camera turning in a room with a box), its
realized and predicted gains checked against a fusion and a scoring done here apart from the study's
loop; the study's variants and anchors; and a short run on the shared real recording, skipped with the
reason where ../shared/data is absent (issue 36)."""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("open3d")

from nbv_prob_cnn.basics.camera import look_rotation, quaternion_from_matrix  # noqa: E402
from nbv_prob_cnn.basics.grid import OCCUPIED, UNKNOWN, probability_with_constant  # noqa: E402
from nbv_prob_cnn.cli import main  # noqa: E402
from nbv_prob_cnn.exploration.gain_study import anchor_frames  # noqa: E402
from nbv_prob_cnn.exploration.scoring_variants import ScoringVariant, cross_variants, parse_vary  # noqa: E402
from nbv_prob_cnn.perception import BagWriter, DepthCamera, Intrinsics, TsdfIntegrator, read_frames  # noqa: E402
from nbv_prob_cnn.perception.depth_camera import room_mesh  # noqa: E402
from nbv_prob_cnn.perception.realized_gain import Fusion, recording_box  # noqa: E402
from nbv_prob_cnn.planners.pose_scoring import score_poses  # noqa: E402
from nbv_prob_cnn.planners.requests import planning_context  # noqa: E402

SCENES = Path(__file__).resolve().parents[3] / "shared" / "data" / "rgbd" / "7scenes_redkitchen"
VOXEL = 0.1
N_FRAMES = 9


@pytest.fixture(scope="module")
def room_bag(tmp_path_factory) -> Path:
    """9 frames, 24 x 18 px, 60 deg: a camera at the middle of a 2 x 2 x 1.5 m room with a box on the
    floor, turning 25 deg per frame about the vertical."""
    import trimesh

    box = trimesh.creation.box(extents=(0.4, 0.4, 0.4))
    box.apply_translation((1.5, 1.0, 0.2))
    camera = DepthCamera([room_mesh(np.zeros(3), np.array([2.0, 2.0, 1.5])), box], Intrinsics.from_hfov(24, 18, 60.0))
    bag = tmp_path_factory.mktemp("room") / "bag"
    with BagWriter(bag) as writer:
        for i in range(N_FRAMES):
            yaw = math.radians(25.0 * i)
            pose = np.eye(4)
            pose[:3, :3] = look_rotation(np.array([math.cos(yaw), math.sin(yaw), -0.3]))
            pose[:3, 3] = (1.0, 1.0, 0.8)
            writer.write_frame(1_000_000_000 * (i + 1), camera.render(pose), camera.intrinsics, pose, "16UC1")
    return bag


def read_rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def test_the_study_ranks_the_services_scores_against_what_each_frame_revealed(room_bag, tmp_path, capsys):
    out = tmp_path / "study"
    args = ["gain-study", "--bag", str(room_bag), "--out", str(out), "--voxel", str(VOXEL), "--anchors", "2",
            "--next", "3", "--methods", "ig,prob_ig", "--vary", "rays_across=0,8", "--resamples", "200",
            "--no-progress"]  # fmt: skip
    assert main(args) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    number = r"-?\d\.\d\d|nan"
    interval = rf"({number}) \[({number}), ({number})\]"
    undefined = r"undefined \(constant predicted gain: it ranks nothing; [^)]*\)"  # ig's is constant in this room
    assert re.fullmatch(rf"rho: ig (?:{interval}|{undefined}), prob_ig {interval} \(2 anchors\)", lines[-1]), lines[-1]
    assert lines[-2].startswith("rho within anchors: ig ")
    assert lines[-3].startswith("rho (baseline): frames since anchor ")
    assert {p.name for p in out.iterdir()} == {"poses.csv", "rho.csv", "rho.png", "summary.md"}
    assert "nbv gain-study" in (out / "summary.md").read_text()

    rows = read_rows(out / "poses.csv")
    labels = {0: "n_rays=4 paper rounded", 8: "across=8 paper rounded", 32: "across=32 paper rounded"}
    # the service's defaults (32 across), --vary, and the baseline: the frames since the anchor
    assert {r["variant"] for r in rows} == {*labels.values(), "baseline"}
    assert len(rows) == 2 * 3 * (2 * 3 + 1)  # anchors x next poses x (methods x variants + the baseline)
    baseline = [r for r in rows if r["variant"] == "baseline"]
    assert [float(r["predicted"]) for r in baseline] == [1.0, 2.0, 3.0] * 2
    assert {r["method"] for r in baseline} == {"frames since anchor"}
    anchors = anchor_frames(N_FRAMES, 2, 3)
    assert anchors == [0, 5] and sorted({int(r["anchor"]) for r in rows}) == anchors

    # apart from the study's loop: fuse the frames up to each anchor, then each next frame alone
    frames = list(read_frames(room_bag))
    fusion = Fusion(VOXEL)
    geometry = recording_box(frames, fusion)
    for anchor in anchors:
        grid = TsdfIntegrator(np.array(geometry.origin), geometry.shape, VOXEL)
        for frame in frames[: anchor + 1]:
            grid.integrate(frame.depth_m, frame.intrinsics, frame.pose_4x4, depth_max=3.0)
        state = grid.ternary()
        nxt = frames[anchor + 1 : anchor + 4]
        for k, frame in enumerate(nxt):
            alone = TsdfIntegrator(np.array(geometry.origin), geometry.shape, VOXEL)
            alone.integrate(frame.depth_m, frame.intrinsics, frame.pose_4x4, depth_max=3.0)
            revealed = int(np.count_nonzero((alone.ternary() != UNKNOWN) & (state == UNKNOWN)))
            surface = int(np.count_nonzero((alone.ternary() == OCCUPIED) & (state == UNKNOWN)))
            mine = [r for r in rows if int(r["anchor"]) == anchor and int(r["frame"]) == anchor + 1 + k]
            assert {int(r["realized"]) for r in mine} == {revealed}
            assert {int(r["realized_surface"]) for r in mine} == {surface}
        # the service's scoring: 3DT data set defaults, the camera's fields of view, prob_ig's P0 0.15
        hfov, vfov = frames[anchor].intrinsics.fov_deg
        context = planning_context("3dt", geometry, "auto", 0, np.random.default_rng(0), hfov, vfov)
        positions = np.array([f.pose_4x4[:3, 3] for f in nxt])
        quats = np.array([quaternion_from_matrix(f.pose_4x4[:3, :3]) for f in nxt])
        prob = probability_with_constant(state, 0.15)
        for across, label in labels.items():
            expected = score_poses(state, prob, geometry, positions, quats, context, score_unknown_cells=True,
                                   rays_across=across).gains  # fmt: skip
            got = [float(r["predicted"]) for r in rows
                   if int(r["anchor"]) == anchor and r["method"] == "prob_ig" and r["variant"] == label]  # fmt: skip
            np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-9)
    assert any(int(r["realized"]) > 0 for r in rows)

    summary = read_rows(out / "rho.csv")
    assert {r["scope"] for r in summary} == {"anchor", "pooled", "within"}
    assert any(r["variant"] == "baseline" and r["scope"] == "within" for r in summary)
    pooled = [r for r in summary if r["scope"] == "pooled" and r["method"] == "prob_ig"]
    assert len(pooled) == 6 and {r["target"] for r in pooled} == {"revealed", "surface"}
    assert all(-1.0 <= float(r["rho"]) <= 1.0 for r in pooled if r["target"] == "revealed")


def test_bad_arguments_name_the_option(room_bag, tmp_path, capsys):
    base = ["gain-study", "--bag", str(room_bag), "--out", str(tmp_path / "x"), "--voxel", str(VOXEL)]
    for extra, name in ((["--methods", "omniscient"], "--methods"), (["--vary", "n_rays"], "--vary"),
                        (["--anchors", "9"], "anchors"), (["--resamples", "0"], "--resamples")):  # fmt: skip
        assert main([*base, *extra, "--no-progress"]) == 2
        assert name in capsys.readouterr().err
    assert main(["gain-study", "--bag", str(tmp_path / "none"), "--out", str(tmp_path / "y")]) == 2
    assert "--bag" in capsys.readouterr().err


def test_variants_cross_from_the_service_defaults():
    base = ScoringVariant(n_rays=4)
    assert parse_vary("n_rays=4,16") == ("n_rays", [4, 16])
    variants = cross_variants(base, ["n_rays=4,16", "rays_across=0,32", "sensor=paper,returns"])
    # n_rays is not read with rays_across: across=32 once per sensor; base first
    assert [v.label for v in variants] == [
        "n_rays=4 paper rounded", "n_rays=4 returns rounded", "across=32 paper rounded", "across=32 returns rounded",
        "n_rays=16 paper rounded", "n_rays=16 returns rounded",
    ]  # fmt: skip
    assert cross_variants(base, []) == [base]
    for bad in ("rays=4", "n_rays=", "n_rays=four", "sampling=coarse"):
        with pytest.raises(ValueError):
            cross_variants(base, [bad])
    with pytest.raises(ValueError, match="twice"):
        cross_variants(base, ["n_rays=4", "n_rays=8"])


def test_anchors_spread_over_the_frames_that_have_next_poses():
    assert anchor_frames(200, 4, 10) == [0, 63, 126, 189]
    assert anchor_frames(5, 1, 4) == [0]
    with pytest.raises(ValueError, match="at most 1 anchors"):
        anchor_frames(5, 2, 4)


@pytest.mark.skipif(not SCENES.is_dir(), reason=f"the shared 7-Scenes recording is absent ({SCENES})")
def test_on_the_shared_kitchen_the_scores_rank_what_the_kinect_revealed(tmp_path, capsys):
    """40 frames (every 5th of the 200), 3 anchors, 4 cm: the study runs on real data and its numbers
    are rank correlations with the frames' own counts."""
    bag = tmp_path / "kitchen"
    assert main(["import-rgbd", "--format", "7scenes", str(SCENES), "--out", str(bag), "--every", "5",
                 "--no-progress"]) == 0  # fmt: skip
    out = tmp_path / "study"
    assert main(["gain-study", "--bag", str(bag), "--out", str(out), "--voxel", "0.04", "--anchors", "3",
                 "--next", "4", "--methods", "prob_ig,cnn_prob", "--vary", "rays_across=0,16", "--resamples", "200",
                 "--no-progress"]) == 0  # fmt: skip
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert re.fullmatch(r"rho: prob_ig -?\d\.\d\d \[.*\], cnn_prob -?\d\.\d\d \[.*\] \(\d anchors\)", last), last
    rows = read_rows(out / "poses.csv")
    assert len(rows) == 3 * 4 * (2 * 3 + 1)  # anchors x next poses x (methods x variants + baseline)
    # the frames reveal cells (the camera moves on), and the own-frustum rays sum 16 x 12 rays per pose
    assert max(int(r["realized"]) for r in rows) > 100
    assert {int(r["rays_in_frustum"]) for r in rows if r["variant"].startswith("across=16")} == {16 * 12}


def test_the_default_vary_keeps_its_promise_and_n_rays_alone_is_refused():
    # issue 48: the help promised n_rays=4,8,16 by default; with rays across the image (the service's default)
    # no variant read n_rays, so the run silently dropped it
    from nbv_prob_cnn.commands.gain_study import DEFAULT_VARY
    from nbv_prob_cnn.planners.pose_scoring import EVALUATE_RAYS_ACROSS

    base = ScoringVariant(n_rays=4, rays_across=EVALUATE_RAYS_ACROSS)
    for spec in DEFAULT_VARY:  # each default key makes as many variants as it has values
        key, values = parse_vary(spec)
        assert len(cross_variants(base, [spec])) == len(set(values) | {getattr(base, key)})
    assert len(cross_variants(base, list(DEFAULT_VARY))) == 4
    with pytest.raises(ValueError, match=r"--vary n_rays: not read .*rays_across 32, the default.*rays_across=0"):
        cross_variants(base, ["n_rays=4,8,16"])
    with pytest.raises(ValueError, match="--vary n_rays"):
        cross_variants(base, ["n_rays=4,8", "rays_across=16,32"])
    assert len(cross_variants(base, ["n_rays=4,8,16", "rays_across=0,32"])) == 4  # read where rays_across is 0


def test_rho_of_a_constant_gain_is_undefined_not_zero():
    from nbv_prob_cnn.basics.geometry import GridGeometry
    from nbv_prob_cnn.exploration.gain_study import GainStudy, PoseRow
    from nbv_prob_cnn.exploration.gain_study_summary import rho_line, summarise

    study = GainStudy(GridGeometry((0.0, 0.0, 0.0), 0.1, (4, 4, 4)), [0, 5])
    realized = {0: [5, 3, 1], 5: [4, 2, 0]}
    for anchor, gains in realized.items():
        for i, gain in enumerate(gains):
            study.rows.append(PoseRow(anchor, anchor + i + 1, "ig", "v", 7.0, gain, False, 10))  # constant
            study.rows.append(PoseRow(anchor, anchor + i + 1, "prob_ig", "v", float(gain), gain, False, 10))
    summary = summarise(study, n_resamples=50)
    ig = {r.scope: r for r in summary if r.method == "ig" and r.scope != "anchor"}
    assert ig["pooled"].constant_gain and math.isnan(ig["pooled"].rho) and ig["within"].constant_gain
    line = rho_line(summary, "v", "pooled")
    assert (
        "ig undefined (constant predicted gain" in line
        and "such as prob_ig ranks" in line
        and "prob_ig 1.00 [1.00, 1.00]" in line
    )
    assert "0.00" not in line


def test_the_surface_target_ranks_against_the_surface_each_frame_saw():
    from nbv_prob_cnn.basics.geometry import GridGeometry
    from nbv_prob_cnn.exploration.gain_study import GainStudy, PoseRow
    from nbv_prob_cnn.exploration.gain_study_summary import rho_line, summarise

    study = GainStudy(GridGeometry((0.0, 0.0, 0.0), 0.1, (4, 4, 4)), [0, 5])
    for anchor in (0, 5):
        # the cells revealed grow with the prediction, the surface seen shrinks with it
        for i, (cells, surface) in enumerate([(1, 9), (4, 6), (8, 2)]):
            study.rows.append(PoseRow(anchor, anchor + i + 1, "cnn_surface", "v", float(i), cells, False, 10, surface))
    summary = summarise(study, n_resamples=50)
    within = {r.target: r.rho for r in summary if r.scope == "within"}
    assert within == {"revealed": 1.0, "surface": -1.0}
    assert rho_line(summary, "v", "within", "surface").startswith("rho within anchors against the surface seen:")
