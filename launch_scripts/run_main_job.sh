#!/usr/bin/env bash
# Set up (idempotent) and run the main job: the full simulated ROS 2 graph with the arm in the loop,
# robot side and our nodes meeting on standard interfaces only (arm_sim as the arm's driver:
# /robot_description, arm and gripper /joint_states, /tf, /tf_static, FollowJointTrajectory;
# sim_camera as the camera's driver: 16UC1 depth + CameraInfo in the optical frame; integrator,
# nbv_planner planning reachable views and sending timed joint trajectories, completion_server,
# gain_server) explores the held-out tabletop scene of seed 1000 through the Explore action with
# the surface gain (cnn_surface, the default; --method cnn_prob for the paper's method), up to 10 views.
# Results: out/main_job/views.csv (incl. joint travel and goal), explored.png, grid.npz, graph.json, logs/.
# Add --no-arm for the free-flying camera.
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$repo/launch_scripts/setup.sh"
cd "$repo"
exec "$repo/.venv/bin/python" launch_scripts/explore_sim.py --dataset 3dt --seed 1000 --views 10 \
  --method cnn_surface --out out/main_job "$@"
