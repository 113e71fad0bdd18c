"""Defaults of the user's path, where they come from the dataset the shipped models saw."""

DATASET_FOV_DEG = 40.0  # the dataset cameras' vertical field of view (DESIGN §3)
DEFAULT_NUM_ANCHORS = 2048  # when the model does not say which N_A its training data used
PREVIEW_FRAMES = 60  # observed + simulated continuation in the preview, frames
PREVIEW_MIN_SIZE = 256  # preview panels are upscaled to at least this many pixels
