"""Training: objectives and the training loop (DESIGN §8)."""
