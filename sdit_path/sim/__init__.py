"""Simulation stage: the ballbar reading along a timed trajectory."""
