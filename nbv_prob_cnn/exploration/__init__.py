"""The exploration loop (start unknown, a random first view, then the planner's views) and the
method comparison built on it (many methods x held-out environments, tables and plots)."""
