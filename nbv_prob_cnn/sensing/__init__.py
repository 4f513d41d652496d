"""Simulated sensing against a ground-truth grid: exact ray traversal of a pinhole depth camera
(:mod:`~nbv_prob_cnn.sensing.observe`) and the depth-noise presets it shares with the simulated
depth-image camera (:mod:`~nbv_prob_cnn.sensing.sensor_noise`)."""
