"""Pictures (matplotlib, Agg backend): an exploration's result and a recorded ROS run."""
