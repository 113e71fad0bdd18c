"""Defaults of the user's path, where they come from the dataset the shipped models saw."""

PREVIEW_FRAMES = 60  # observed + simulated continuation in the preview, frames
PREVIEW_MIN_SIZE = 256  # preview panels are upscaled to at least this many pixels
