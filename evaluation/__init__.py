"""Metrics (retrieval, loop closures, trajectory, relations) and benchmark runners."""
