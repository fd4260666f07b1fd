"""File formats: pose files (KITTI, TUM)."""
