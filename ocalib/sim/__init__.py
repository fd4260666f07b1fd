"""Numerical simulation of rigs and trajectories (the paper's section 3.1)."""
