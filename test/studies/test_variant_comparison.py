"""The paper-vs-original table (studies.variant_comparison) by hand."""

import numpy as np

BACKENDS = ["numpy", "opencl"]
E, O, U = 0, 1, -1  # noqa: E741
X = np.array([[1.0, 0.0]])


def test_variant_comparison_pairs_environments_by_hand(tmp_path):
    import json

    from studies.variant_comparison import compare

    dirs = {"paper": tmp_path / "paper" / "2d", "original": tmp_path / "original" / "2d"}
    curves = {("paper", 120): [0.9, 0.8, 0.7], ("paper", 121): [0.9, 0.6, 0.5], ("paper", 122): [0.9, 0.9, 0.9],
              ("original", 120): [0.9, 0.7, 0.6], ("original", 121): [0.9, 0.5, 0.3]}  # fmt: skip
    for (variant, seed), values in curves.items():
        path = dirs[variant] / "runs" / f"2d_prob_ig_seed{seed}.csv"
        path.parent.mkdir(parents=True, exist_ok=True)
        rows = [f"{v},{v},1.0" for v in values]
        path.write_text("unknown_fraction,unknown_fraction_all,time_total_s\n" + "\n".join(rows) + "\n")
        meta = {"views": 3} | ({"gain_variant": "original"} if variant == "original" else {})
        path.with_suffix(".json").write_text(json.dumps(meta))
    table, csv_text, stacked, seeds = compare("2d", dirs, ("prob_ig",), views=3, at=(3,))
    assert seeds == [120, 121]  # 122 has no original run
    assert np.allclose(stacked[("original", "prob_ig")][:, 2], [0.6, 0.3])
    # paired differences -0.1 and -0.2: mean -0.15, standard error 0.0707 / sqrt(2) = 0.05
    assert "| prob_ig | original − paper | 2 | -0.1500 ± 0.0500 | |" in table
    assert "prob_ig,paper,2,0.60000,0.10000" in csv_text
