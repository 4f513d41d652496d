"""``nbv study arm_compare`` run on a tiny case and its CSV outputs read back, for the study's
tests (``test/shared`` is on the tests' import path)."""

from __future__ import annotations

import csv
from pathlib import Path

from studies.__main__ import main


def run_arm_compare(out: Path, args: list[str]) -> Path:
    """Runs ``nbv study arm_compare --out out *args``, which must succeed; returns ``out``."""
    assert main(["arm_compare", "--out", str(out), *args]) == 0
    return out


def read(path: Path) -> list[dict]:
    """The rows of a CSV file with a header line."""
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def run_log(out: Path, seed: int, config: str) -> list[dict]:
    """The per-view log of the run of scene ``seed`` in configuration ``config``."""
    return read(out / "runs" / f"seed{seed}_{config}.csv")
