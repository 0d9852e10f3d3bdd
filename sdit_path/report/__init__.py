"""Reports: the plan manifest and human-readable summaries."""
