"""rclpy nodes (one per module) and the message conversions they share. Nodes only convert
messages and call the core library."""
