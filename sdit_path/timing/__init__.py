"""Timing stage: path limits, ruckig profiles and timed, sampled trajectories."""
