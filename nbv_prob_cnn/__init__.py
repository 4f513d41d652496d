"""nbv_prob_cnn: next best view planning for depth cameras with a completion CNN and
probabilistic ray casting (Monica & Aleotti). The core library imports no ROS; the rclpy
nodes live in :mod:`nbv_prob_cnn.ros`."""

__version__ = "0.1.0"
