"""Interference stage: the collision scene and the clearance check along the paths."""
