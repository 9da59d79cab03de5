"""BINO float model, training and export (PyTorch)."""
