#!/usr/bin/env bash
# Set up (idempotent) and run the main job: a simulated exploration of a default 3D
# tabletop scene with the probabilistic planner. Results go to out/main_job/.
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$repo/launch_scripts/setup.sh"
cd "$repo"
mkdir -p out/main_job
exec "$repo/.venv/bin/nbv" explore --dataset 3dt --method prob_ig --views 20 --seed 1000 \
  --log out/main_job/explore.csv --png out/main_job/explore.png "$@"
