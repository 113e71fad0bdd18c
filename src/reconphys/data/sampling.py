"""Per-sample randomness: physical attributes, orientation, initial velocity and drop height.

Distributions (documented in docs/dataset.md; ranges from docs/design.md#attribute-ranges):

- mass m (kg per anchor), stiffness k (N per unit strain), damping d (N·s per unit strain rate):
  uniform on their ranges (the paper's protocol) or log-uniform (``distribution="log-uniform"``),
  drawn independently; friction f: uniform on [0, 1].
- orientation: uniform on SO(3) (a normalised 4D Gaussian as quaternion).
- angular velocity: uniform direction, speed uniform on [0, max_angular_speed] rad/s, about the
  anchors' centroid; horizontal velocity: each axis uniform on ±max_horizontal_speed m/s.
- launch: a **toss** with probability ``toss_fraction``, else a **drop**. A drop keeps the
  horizontal velocity above and starts over the origin (the cameras' target). A toss replaces it
  by a horizontal speed uniform on ``toss_speed_range`` in a uniform direction, lowered where
  needed so that the path it would take with the sample's friction (flight, then Coulomb sliding
  to the clip's end, :func:`toss_travel`) fits inside the views (:func:`toss_path_budget`); it
  starts half that path before the origin, so it slides across the middle of the views.
- first ground contact: a target time ``t_c`` uniform on ``contact_frame_range`` frames; the
  vertical velocity v_z is uniform on the part of [−max_vertical_speed, max_vertical_speed] that
  keeps the free-fall drop height ``½ g t_c² − v_z t_c`` inside ``drop_height_range``; the height
  is then solved for the rotating object so that its lowest anchor first reaches the ground at
  ``t_c`` (see :func:`centroid_height_for_contact`).

Each sample draws from its own generator seeded by (dataset seed, object id, sample index), in a
fixed order, so a sample never depends on which other samples are generated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..physics import GRAVITY, seed_from_id
from .settings import DataSettings

CONTACT_TOLERANCE = 1e-3  # metres: an anchor this close to the ground counts as touching it
GRAVITY_MAGNITUDE = -GRAVITY[2]  # m/s², along −z
TIME_GRID = 128  # samples of [0, t_c] on which the rotating object's lowest point is tracked


@dataclass(frozen=True)
class SampleSpec:
    """Everything random about one sample (SI units; world = rotation · object + translation)."""

    mass: float
    stiffness: float
    damping: float
    friction: float
    rotation: np.ndarray  # [3, 3] float64, world ← object frame
    linear_velocity: tuple[float, float, float]  # m/s
    angular_velocity: tuple[float, float, float]  # rad/s about the anchors' centroid
    target_contact_time: float  # seconds
    launch: str = "drop"  # "drop" or "toss"
    start: tuple[float, float] = (0.0, 0.0)  # anchors' centroid over the ground at frame 0, m

    @property
    def attributes(self) -> dict[str, float]:
        return {
            "mass": self.mass,
            "stiffness": self.stiffness,
            "damping": self.damping,
            "friction": self.friction,
        }


def sample_seed(dataset_seed: int, object_id: str, sample_index: int) -> int:
    return seed_from_id(f"sample:{dataset_seed}:{object_id}:{sample_index}")


def _draw(rng: np.random.Generator, bounds: tuple[float, float], log: bool) -> float:
    low, high = bounds
    if log and low > 0:
        return float(math.exp(rng.uniform(math.log(low), math.log(high))))
    return float(rng.uniform(low, high))


def random_rotation(rng: np.random.Generator) -> np.ndarray:  # [3, 3]
    """Uniform random rotation (Shoemake: a normalised 4D Gaussian is a uniform unit quaternion).

    The matrix is :func:`reconphys.geometry.quaternion_to_matrix` written in numpy: the dataset a
    seed makes must not change, even by round-off, so this numeric path stays as it is.
    """
    q = rng.standard_normal(4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def draw_sample(settings: DataSettings, object_id: str, sample_index: int) -> SampleSpec:
    """The random part of sample ``sample_index`` of ``object_id`` (see the module docstring)."""
    rng = np.random.default_rng(sample_seed(settings.seed, object_id, sample_index))
    log = settings.distribution == "log-uniform"
    mass = _draw(rng, settings.mass_range, log)
    stiffness = _draw(rng, settings.stiffness_range, log)
    damping = _draw(rng, settings.damping_range, log)
    friction = _draw(rng, settings.friction_range, False)
    rotation = random_rotation(rng)
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    angular = axis * rng.uniform(0.0, settings.max_angular_speed)
    horizontal = rng.uniform(-settings.max_horizontal_speed, settings.max_horizontal_speed, 2)
    t_c = float(rng.uniform(*settings.contact_frame_range)) * settings.frame_dt
    fall = 0.5 * GRAVITY_MAGNITUDE * t_c * t_c  # free-fall distance in t_c from rest
    low, high = settings.drop_height_range
    v_max = settings.max_vertical_speed
    v_low, v_high = max(-v_max, (fall - high) / t_c), min(v_max, (fall - low) / t_c)
    if v_low > v_high:  # the ranges cannot both hold: keep the height range
        v_low = v_high = (fall - min(max(fall, low), high)) / t_c
    v_z = float(rng.uniform(v_low, v_high))
    # The launch: drawn after everything above, always in the same order (a seed's drops stay).
    toss = bool(rng.uniform() < settings.toss_fraction)
    heading = rng.uniform(0.0, 2.0 * math.pi)
    speed = float(rng.uniform(*settings.toss_speed_range))
    start = np.zeros(2)
    if toss:
        duration = (settings.num_frames - 1) * settings.frame_dt
        budget = toss_path_budget(settings)
        speed = _fitting_speed(speed, budget, friction, t_c, duration)
        direction = np.array([math.cos(heading), math.sin(heading)])
        horizontal = speed * direction
        start = -0.5 * toss_travel(speed, friction, t_c, duration) * direction
    return SampleSpec(
        mass=mass,
        stiffness=stiffness,
        damping=damping,
        friction=friction,
        rotation=rotation,
        linear_velocity=(float(horizontal[0]), float(horizontal[1]), v_z),
        angular_velocity=tuple(float(a) for a in angular),
        target_contact_time=t_c,
        launch="toss" if toss else "drop",
        start=(float(start[0]), float(start[1])),
    )


def toss_path_budget(settings: DataSettings) -> float:
    """How far (m) a tossed object's centroid may travel and stay in every view: the width of the
    ground the camera sees around its target (the vertical field of view at the camera's
    distance; the images are square), less the object's size, with a 10 % margin."""
    half_width = settings.camera_radius * math.tan(math.radians(settings.camera_fov_deg) / 2)
    return max(0.0, 0.9 * 2.0 * (half_width - 0.5 * settings.size))


def toss_travel(speed: float, friction: float, contact_time: float, duration: float) -> float:
    """Horizontal distance (m) a rigid body launched at ``speed`` (m/s) covers in ``duration``
    seconds: flight until ``contact_time``, then Coulomb sliding (deceleration μg) until it stops.
    An upper bound for our objects: the impact and their deformation only take speed away."""
    flight = speed * min(contact_time, duration)
    sliding_time = max(0.0, duration - contact_time)
    deceleration = friction * GRAVITY_MAGNITUDE
    if deceleration > 0 and deceleration * sliding_time >= speed:  # stops before the end
        return flight + speed * speed / (2.0 * deceleration)
    return flight + speed * sliding_time - 0.5 * deceleration * sliding_time**2


def _fitting_speed(
    speed: float, budget: float, friction: float, contact_time: float, duration: float
) -> float:
    """``speed``, or the largest speed whose :func:`toss_travel` fits in ``budget`` (bisection:
    the travel grows with the speed)."""
    if toss_travel(speed, friction, contact_time, duration) <= budget:
        return speed
    low, high = 0.0, speed
    for _ in range(50):
        middle = 0.5 * (low + high)
        fits = toss_travel(middle, friction, contact_time, duration) <= budget
        low, high = (middle, high) if fits else (low, middle)
    return low


def axis_angle_matrices(rotation_vectors: np.ndarray) -> np.ndarray:  # [T, 3] → [T, 3, 3]
    """Rodrigues' formula for rotation vectors (axis × angle in radians).

    The numpy twin of :func:`reconphys.geometry.axis_angle_to_matrix` (which floors the angle
    differently, for gradients), kept so that generated drop heights stay bit for bit the same.
    """
    angle = np.linalg.norm(rotation_vectors, axis=-1, keepdims=True)
    axis = rotation_vectors / np.maximum(angle, 1e-12)
    x, y, z = axis[:, 0], axis[:, 1], axis[:, 2]
    zero = np.zeros_like(x)
    cross = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(-1, 3, 3)
    s, c = np.sin(angle)[..., None], np.cos(angle)[..., None]
    return np.eye(3) + s * cross + (1 - c) * (cross @ cross)


def centroid_height_for_contact(
    relative_anchors: np.ndarray,  # [N_A, 3] anchors minus their centroid, world axes, metres
    vertical_velocity: float,  # m/s
    angular_velocity: tuple[float, float, float],  # rad/s
    contact_time: float,  # s
    gravity: float = GRAVITY_MAGNITUDE,  # m/s², along −z
) -> float:  # metres
    """Centroid height at t = 0 for which the rigidly moving object first touches z = 0 at
    ``contact_time``: the largest ½ g t² − v_z t − lowest(t) over t ∈ [0, t_c].

    Before contact the springs are at rest and the motion is rigid (free fall plus rotation about
    the centroid), so ``lowest(t)``, the lowest anchor relative to the centroid, follows from the
    angular velocity. If rotation would bring a point down earlier, contact happens earlier than
    ``contact_time`` (never later).
    """
    times = np.linspace(0.0, contact_time, TIME_GRID)
    rotations = axis_angle_matrices(times[:, None] * np.asarray(angular_velocity)[None])
    lowest = (relative_anchors @ rotations[:, 2, :].T).min(0)  # [T] z of R(ωt)·r, minimum
    needed = 0.5 * gravity * times**2 - vertical_velocity * times - lowest
    return float(needed.max())


def contact_frame(
    anchors: np.ndarray,  # [T, N_A, 3] metres
    ground_height: float = 0.0,
    tolerance: float = CONTACT_TOLERANCE,
) -> int:
    """First frame whose lowest anchor is within ``tolerance`` of the ground; −1 if none."""
    touching = np.asarray(anchors)[..., 2].min(-1) <= ground_height + tolerance
    return int(np.argmax(touching)) if touching.any() else -1
