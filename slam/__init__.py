"""The host: odometry front ends, the gtsam pose graph, the mapper pipeline, maps and the CLI."""
