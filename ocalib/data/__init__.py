"""Datasets: the native rig layout and loaders for real sequence layouts."""
