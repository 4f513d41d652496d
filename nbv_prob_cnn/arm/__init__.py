"""The manipulator in the loop (no ROS): robot model, camera IK, collision checks, the capability
map, the exact feasibility check of ranked views with a motion cost, and the self-filter."""
