"""Method comparison: runs are logged, summarised and resumable (redone when their weights changed)."""

import hashlib
import json
import shutil

import numpy as np

from nbv_prob_cnn.exploration.evaluation import (
    WEIGHTS_KEY,
    evaluate,
    read_run,
    run_path,
    run_status,
    summary_table,
    weights_fingerprint,
)


def test_evaluate_summarises_and_resumes(tmp_path):
    logs = evaluate("3du", ["random", "prob_ig"], [120, 121], 4, tmp_path, progress=False, workers=0)
    assert {m: len(r) for m, r in logs.items()} == {"random": 2, "prob_ig": 2}
    paths = [run_path(tmp_path, "3du", m, s) for m in ("random", "prob_ig") for s in (120, 121)]
    mtimes = [p.stat().st_mtime_ns for p in paths]
    # every method starts from the same random first view of an environment
    first = [read_run(run_path(tmp_path, "3du", m, 120)).unknown_fraction[0] for m in ("random", "prob_ig")]
    assert first[0] == first[1]
    table = summary_table(logs, [2, 4])
    final = np.mean([read_run(run_path(tmp_path, "3du", "prob_ig", s)).unknown_fraction[3] for s in (120, 121)])
    assert f"{final:.4f}" in table.splitlines()[3]
    again = evaluate("3du", ["random", "prob_ig"], [120, 121], 4, tmp_path, progress=False, workers=0)
    assert [p.stat().st_mtime_ns for p in paths] == mtimes  # read back, not recomputed
    np.testing.assert_array_equal(again["prob_ig"][1].unknown_fraction, logs["prob_ig"][1].unknown_fraction)


def test_run_status_by_hand(tmp_path):
    path = tmp_path / "2d_cnn_prob_seed120.csv"
    assert run_status(path, 3, "abc") == "missing"
    path.write_text("iteration\n0\n1\n2\n")
    assert run_status(path, 3) == "done"  # no .json: the rows count; a method without weights
    assert run_status(path, 4) == "short"
    assert run_status(path, 3, "abc") == "other weights"  # weights, but none recorded
    meta = path.with_suffix(".json")
    meta.write_text(json.dumps({"views": 100, "stop_reason": "no view", WEIGHTS_KEY: "abc"}))
    assert run_status(path, 100, "abc") == "done" and run_status(path, 101, "abc") == "short"
    assert run_status(path, 100, "abd") == "other weights" and run_status(path, 100) == "other weights"
    meta.write_text(json.dumps({"views": 100}))  # written before fingerprints were recorded
    assert run_status(path, 100) == "done" and run_status(path, 100, "abc") == "other weights"
    # a surface method's run is kept only for the blend it ran with
    meta.write_text(json.dumps({"views": 100, "surface_blend": 0.8}))  # made before the image re-ranking
    assert run_status(path, 100, surface_blend=0.8) == "other image re-ranking"
    assert run_status(path, 100, surface_blend=0.8, image_rerank=0) == "done"
    assert run_status(path, 100, surface_blend=0.9, image_rerank=0) == "other surface blend"
    assert run_status(path, 100) == "other surface blend"  # not a surface method's run
    # ... and for the views it re-ranked by their image rays
    meta.write_text(json.dumps({"views": 100, "surface_blend": 0.8, "image_rerank": 20}))
    assert run_status(path, 100, surface_blend=0.8, image_rerank=20) == "done"
    assert run_status(path, 100, surface_blend=0.8, image_rerank=10) == "other image re-ranking"
    assert run_status(path, 100, surface_blend=0.8) == "other image re-ranking"
    meta.unlink()
    assert run_status(path, 3, surface_blend=0.8) == "other surface blend"  # no .json: no blend recorded
    assert run_status(path, 3, image_rerank=20) == "other image re-ranking"


def test_runs_with_other_weights_are_redone(tmp_path, monkeypatch, capsys):
    """A run is kept only while the weights its method reads are those it ran with; methods
    without weights are never redone."""
    import torch

    from nbv_prob_cnn.completion.inference import weights_dir

    shipped = weights_dir() / "3du_flat_city_cnn.pt"
    monkeypatch.setenv("NBV_WEIGHTS_DIR", str(tmp_path / "weights"))
    (tmp_path / "weights").mkdir()
    weights = tmp_path / "weights" / "3du_flat_city_cnn.pt"
    shutil.copyfile(shipped, weights)
    methods, out = ["random", "flat_city_cnn"], tmp_path / "eval"
    evaluate("3du", methods, [120], 2, out, progress=False, workers=0)
    paths = {m: run_path(out, "3du", m, 120) for m in methods}
    metas = {m: json.loads(p.with_suffix(".json").read_text()) for m, p in paths.items()}
    assert metas["random"][WEIGHTS_KEY] is None
    assert metas["flat_city_cnn"][WEIGHTS_KEY] == hashlib.sha256(shipped.read_bytes()).hexdigest()[:16]
    assert weights_fingerprint("3du", "flat_city_cnn") == metas["flat_city_cnn"][WEIGHTS_KEY]
    mtimes = {m: p.stat().st_mtime_ns for m, p in paths.items()}

    evaluate("3du", methods, [120], 2, out, progress=True, workers=0)  # same weights: both kept
    assert {m: p.stat().st_mtime_ns for m, p in paths.items()} == mtimes
    assert "redoing" not in "".join(capsys.readouterr())

    payload = torch.load(weights, weights_only=True)
    payload["state_dict"]["final.bias"] += 0.5  # retrained weights
    torch.save(payload, weights)
    new = hashlib.sha256(weights.read_bytes()).hexdigest()[:16]
    evaluate("3du", methods, [120], 2, out, progress=True, workers=0)
    assert paths["random"].stat().st_mtime_ns == mtimes["random"]
    assert paths["flat_city_cnn"].stat().st_mtime_ns != mtimes["flat_city_cnn"]
    assert json.loads(paths["flat_city_cnn"].with_suffix(".json").read_text())[WEIGHTS_KEY] == new
    assert f"3du flat_city_cnn: redoing 1 run(s) made with other weights than the current ones (sha256 {new})" in (
        capsys.readouterr().err
    )


def test_guarded_runs_sit_beside_the_plain_ones(tmp_path):
    """``guard=True``: runs named ``*_guarded_*`` with the threshold in their ``.json`` (5e-5 of the
    64³ 3DU grid = 14 cells); the plain runs in the same folder are neither read nor rewritten."""
    from nbv_prob_cnn.exploration.evaluation import GUARD_KEY

    plain = evaluate("3du", ["prob_ig"], [120], 4, tmp_path, progress=False, workers=0)
    plain_path = run_path(tmp_path, "3du", "prob_ig", 120)
    mtime = plain_path.stat().st_mtime_ns
    guarded = evaluate("3du", ["prob_ig"], [120], 4, tmp_path, progress=False, workers=0, guard=True)
    path = run_path(tmp_path, "3du", "prob_ig", 120, guarded=True)
    assert path.name == "3du_prob_ig_guarded_seed120.csv" and plain_path.stat().st_mtime_ns == mtime
    meta = json.loads(path.with_suffix(".json").read_text())
    assert meta[GUARD_KEY] == 14 and GUARD_KEY not in json.loads(plain_path.with_suffix(".json").read_text())
    assert run_status(path, 4, None, "paper", 14) == "done" and run_status(path, 4, None, "paper", 20) == "other guard"
    assert run_status(path, 4) == "other guard" and run_status(plain_path, 4, None, "paper", 14) == "other guard"
    # same first view; the columns the guard reports exist in both
    assert guarded["prob_ig"][0].unknown_fraction[0] == plain["prob_ig"][0].unknown_fraction[0]
    with open(path) as handle:
        header = handle.readline().strip().split(",")
    assert header[-4:] == ["changed_cells", "ruled_out_views", "surface_coverage", "new_surface_cells"]
