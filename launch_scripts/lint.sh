#!/usr/bin/env bash
# Static checks of the whole tree (the product, ros/ included, the studies and the tests):
# ruff lint, ruff format and mypy. Run by run_tests.sh before the test suite; each failure names
# file and line.
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$repo"
py="$repo/.venv/bin/python"
echo "[lint] ruff check"
"$py" -m ruff check --quiet .
echo "[lint] ruff format --check"
"$py" -m ruff format --check --quiet .
echo "[lint] mypy nbv_prob_cnn studies"
"$py" -m mypy --no-error-summary nbv_prob_cnn studies
echo "[lint] clean"
