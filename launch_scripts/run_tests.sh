#!/usr/bin/env bash
# Set up (idempotent), run the static checks (launch_scripts/lint.sh) and the whole test suite
# (test/unit, test/ros, test/studies).
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$repo/launch_scripts/setup.sh"
cd "$repo"
bash "$repo/launch_scripts/lint.sh"
# --durations: the slowest tests are printed with every run, so the suite time stays visible.
# NBV_TEST_WORKERS (default 2) pytest processes share the tests a file at a time (pytest-xdist,
# --dist loadfile: a file's module fixtures are built once); 1 runs them in this process. Every ROS
# test holds its own ROS_DOMAIN_ID (test/conftest.py) and the caches are written atomically, so
# the workers never meet.
workers="${NBV_TEST_WORKERS:-2}"
if [ "$workers" -gt 1 ]; then
    exec "$repo/.venv/bin/python" -m pytest -q --durations=15 -n "$workers" --dist loadfile "$@" test
fi
exec "$repo/.venv/bin/python" -m pytest -q --durations=15 "$@" test
