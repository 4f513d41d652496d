#!/usr/bin/env bash
# Set up (idempotent), run the static checks (launch_scripts/lint.sh) and the whole test suite
# (test/unit, test/ros, test/studies).
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$repo/launch_scripts/setup.sh"
cd "$repo"
bash "$repo/launch_scripts/lint.sh"
# --durations: the slowest tests are printed with every run, so the suite time stays visible
exec "$repo/.venv/bin/python" -m pytest -q --durations=15 "$@" test
