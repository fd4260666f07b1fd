"""The head driven over a stream or a recording: frame by frame (PyTorch or the compiled frame update), a recorded
sequence at once, the batch and ``AX = YB`` references, and what they share: settings, results, change tests,
clock offsets."""
