"""Defaults of the user's path, where they come from the dataset the shipped models saw."""

PREVIEW_FRAMES = 60  # observed + simulated continuation in the preview, frames
PREVIEW_MIN_SIZE = 256  # preview panels are upscaled to at least this many pixels
# ... and rendered at most this many pixels a side (a phone's recording, read at 640 px, would
# take longer to preview than to predict: docs/usage.md#what-predict-writes)
PREVIEW_MAX_SIDE = 320
