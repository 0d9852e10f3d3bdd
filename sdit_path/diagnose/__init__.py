"""Diagnosing the gap between a simulated and a measured ballbar trace."""
