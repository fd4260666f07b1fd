"""File formats: pose files (KITTI, TUM); JSON-safe numbers."""
