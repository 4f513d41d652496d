"""Method comparison: runs are logged, summarised and resumable."""

import numpy as np

from nbv_prob_cnn.evaluation import evaluate, read_run, run_path, summary_table


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
