#!/usr/bin/env bash
# Set up (idempotent) and run the whole test suite.
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$repo/launch_scripts/setup.sh"
cd "$repo"
# --durations: the slowest tests are printed with every run, so the suite time stays visible
exec "$repo/.venv/bin/python" -m pytest -q --durations=15 "$@" test
