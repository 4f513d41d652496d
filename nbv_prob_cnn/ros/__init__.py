"""rclpy nodes (one per module) and the message conversions they share. Nodes only convert
messages and call the core library."""

#: The runnable nodes (``ros2 run nbv_prob_cnn <name>`` / ``nbv node <name>``); setup.py reads
#: this list for the console scripts, so keep this module free of imports.
NODES = (
    "sim_camera",
    "integrator",
    "bag_replay",
    "bag_record",
    "completion_server",
    "gain_server",
    "nbv_planner",
    "arm_sim",
    "octomap_bridge",
)
