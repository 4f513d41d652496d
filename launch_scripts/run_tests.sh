#!/usr/bin/env bash
# Set up (idempotent) and run the whole test suite.
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$repo/launch_scripts/setup.sh"
cd "$repo"
exec "$repo/.venv/bin/python" -m pytest -q "$@" test
