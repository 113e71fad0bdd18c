"""From a user's recording to an observation the models read (docs/usage.md#the-input).

- :mod:`.video`      decode a video file or a folder of frames; resample time to ``frame_dt``
- :mod:`.interpolate`  frames between two recorded ones (a recording at 30 fps, not 33.3)
- :mod:`.masks`      the object's mask: a mask folder, an alpha channel or background subtraction
- :mod:`.camera`     the camera file (K, world_to_cam, ground height) and the default camera
- :mod:`.placement`  put given Gaussians where the first frame shows the object; initial velocity
- :mod:`.observation`  all of the above → :class:`Observation` (masked frames + camera)
"""

from .camera import CameraSpec, default_camera, read_camera, write_camera
from .observation import Observation, load_observation

__all__ = [
    "CameraSpec",
    "Observation",
    "default_camera",
    "load_observation",
    "read_camera",
    "write_camera",
]
