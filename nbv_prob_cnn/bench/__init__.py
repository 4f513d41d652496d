"""Benchmarks behind ``nbv bench``, beside (not inside) the library stages: planning iterations
and ray-casting kernels (:mod:`~nbv_prob_cnn.bench.planning`), the arm's feasibility checks
(:mod:`~nbv_prob_cnn.bench.arm`), robot rendering for the self-filter
(:mod:`~nbv_prob_cnn.bench.render`), depth fusion (:mod:`~nbv_prob_cnn.bench.fusion`) and the ROS
graph's latency (:mod:`~nbv_prob_cnn.bench.ros_latency`, the only one that imports rclpy). Each
measures the compared variants side by side in one run and prints their ratios."""
