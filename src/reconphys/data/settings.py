"""Generation settings of a synthetic dataset (docs/design.md#attribute-ranges,
docs/design.md#synthetic-dataset) and the presets.

Every number that changes what ``make-data`` writes lives in :class:`DataSettings`; the manifest
stores them, a resumed run must use the same ones, and :meth:`DataSettings.fingerprint` tags every
sample with them. How a run is executed (workers, shard, device) is not part of the settings.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import asdict, dataclass, fields, replace

from ..config_loader import load_settings, read_table
from ..errors import InputError
from ..physics import ATTRIBUTE_RANGES

DISTRIBUTIONS = ("uniform", "log-uniform")
MAX_STRETCH = 20.0  # of a mesh along one axis (stretch_range)
SCENES = ("plain", "realistic")
SCENE_FIELDS = (
    "scene",
    "object_size_range",
    "fov_range_deg",
    "elevation_range_deg",
    "framing_range",
    "noise_range",
    "video_quality_range",
    "vivid_share",
    "contrast_share",
    "hand_share",
    "grey_share",
    "exposure_range_s",
    "readout_range_s",
)


@dataclass(frozen=True)
class DataSettings:
    """What to generate. Units: metres, seconds, m/s, rad/s; frame counts are video frames."""

    source: str = "procedural"  # "procedural", "pybullet", "objaverse" or a folder of meshes
    seed: int = 0
    objects: int = 8  # training objects
    test_objects: int = 0  # held-out objects (split by object, never by sample)
    samples_per_object: int = 2  # attribute samples per training object
    test_samples_per_object: int = 2  # attribute samples per test object
    resolution: int = 128  # image width = height, pixels
    num_frames: int = 30  # video frames, frame 0 = the initial state
    frame_dt: float = 0.03  # seconds between frames
    size: float = 0.5  # largest bounding-box side of every object, metres
    num_gaussians: int = 2000  # Gaussians per object (at most, for Gaussian PLY inputs)
    num_anchors: int = 256  # N_A
    num_neighbors: int = 32  # K of the kNN springs
    binding_neighbors: int = 16  # n_b
    binding_power: float = 2.0  # p_b
    spring_exponent: float = 0.5  # p_k
    restitution: float = 0.0  # e
    min_substeps: int = 100  # floor of the substeps per frame (more when stability needs them)
    distribution: str = "uniform"  # of m, k and d: "uniform" (the paper) or "log-uniform"
    mass_range: tuple[float, float] = ATTRIBUTE_RANGES["mass"]  # kg per anchor
    stiffness_range: tuple[float, float] = ATTRIBUTE_RANGES["stiffness"]  # N per unit strain
    damping_range: tuple[float, float] = ATTRIBUTE_RANGES["damping"]  # N·s per unit strain rate
    friction_range: tuple[float, float] = ATTRIBUTE_RANGES["friction"]  # Coulomb coefficient
    contact_frame_range: tuple[float, float] = (5.0, 14.0)  # target first contact, frames
    drop_height_range: tuple[float, float] = (0.05, 0.5)  # lowest anchor at frame 0, metres
    max_vertical_speed: float = 1.2  # |v_z| at frame 0, m/s
    max_horizontal_speed: float = 0.3  # per horizontal axis, m/s
    max_angular_speed: float = 2.0  # rad/s, random axis
    toss_fraction: float = 0.5  # share of tosses (the rest are drops), see data/sampling.py
    toss_speed_range: tuple[float, float] = (0.5, 1.5)  # horizontal speed of a toss, m/s
    camera_radius: float = 2.0  # metres from the target
    camera_fov_deg: float = 40.0  # vertical
    camera_elevation_deg: float = 15.0
    camera_target: tuple[float, float, float] = (0.0, 0.0, 0.3)  # metres
    objaverse_uids: str = ""  # optional file of Objaverse UIDs (one a line) to draw from
    # Mesh files stretched along a random axis by a factor drawn log-uniformly from this range
    # before normalisation (data/source_base.py), so that a source of compact meshes also gives
    # long, thin objects; (1, 1): each mesh as its file has it.
    stretch_range: tuple[float, float] = (1.0, 1.0)
    # The look (docs/design.md#synthetic-dataset): "plain" (object on black, the cameras above) or
    # "realistic" (data/scene.py: ground, backdrop, light and shadow, a camera per sample framed
    # on the motion, sized objects, noise, compression; the fields below apply to it only).
    scene: str = "plain"
    object_size_range: tuple[float, float] = (0.1, 0.6)  # largest side, metres (replaces size)
    fov_range_deg: tuple[float, float] = (30.0, 65.0)  # vertical field of view
    elevation_range_deg: tuple[float, float] = (3.0, 35.0)  # camera above the motion's centre
    framing_range: tuple[float, float] = (0.45, 0.85)  # share of the image the motion spans
    noise_range: tuple[float, float] = (0.0, 0.02)  # sensor noise σ, colour units in [0, 1]
    video_quality_range: tuple[float, float] = (4.0, 8.0)  # H.264 quality 0–10 (CRF 31 to 10)
    # Share of realistic scenes drawn vivid (render/scene.py vivid_look: saturated many-coloured
    # floors and backdrops, a printed pattern on the object), from a random stream of its own:
    # at 0 every scene is drawn as before
    vivid_share: float = 0.0
    # Share of realistic scenes whose floor is high-contrast (render/scene.py contrast_look: an
    # engine's checker floor, dark and bright), after the vivid draw, from a stream of its own
    contrast_share: float = 0.0
    # Share of realistic samples released from a hand (render/hand.py: a palm, fingers and a
    # forearm holding the object's top at frame 0, withdrawn or kept still after), from a stream
    # of its own; the stored masks are the object's visible pixels
    hand_share: float = 0.0
    # Share of realistic samples whose object is grey (render/scene.py grey_look: its colours
    # mixed 85–100 % towards their grey: grey, white or black plastic and metal), from a stream
    # of its own; meshes bring colourful textures, and a real object often has none
    grey_share: float = 0.0
    # How long each realistic sample's shutter stays open, seconds, drawn uniformly from this
    # range from a stream of its own (data/scene.py): the object blurred along its motion over
    # that time, centred on the frame's time (data/generate.py shutter_anchors). A phone's video
    # indoors keeps it open up to the whole frame (1/30 s); at (0, 0) every frame is sharp
    exposure_range_s: tuple[float, float] = (0.0, 0.0)
    # How long each realistic sample's sensor takes to read its rows, top to bottom, seconds,
    # drawn uniformly from this range from a stream of its own (a phone's rolling shutter, 10–30
    # ms; data/generate.py reads the rows in bands, each at its own time); at (0, 0) every row
    # is read at once
    readout_range_s: tuple[float, float] = (0.0, 0.0)

    def to_dict(self) -> dict:
        out = asdict(self)
        return {k: list(v) if isinstance(v, tuple) else v for k, v in out.items()}

    @staticmethod
    def from_dict(data: dict, where: str = "settings") -> DataSettings:
        names = {f.name for f in fields(DataSettings)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise InputError(f"unknown settings {unknown}", source=where)
        values = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
        return DataSettings(**values).validated()

    def fingerprint(self) -> str:
        """Short hash of the settings: tags every object and sample written with them. The
        realistic look's fields count only when it is chosen (plain datasets made before they
        existed keep their fingerprint)."""
        values = self.to_dict()
        if self.scene == "plain":
            for name in SCENE_FIELDS:
                values.pop(name)
        if not self.stretched:  # datasets made before the stretch existed keep theirs
            values.pop("stretch_range")
        for name in ("vivid_share", "contrast_share", "hand_share", "grey_share"):  # nor those
            if self.scene != "plain" and not getattr(self, name):
                values.pop(name)
        for name in ("exposure_range_s", "readout_range_s"):  # nor the shutter's
            if self.scene != "plain" and not max(getattr(self, name)):
                values.pop(name)
        text = json.dumps(values, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    @property
    def stretched(self) -> bool:
        """True when mesh files are stretched (``stretch_range`` above 1)."""
        return max(self.stretch_range) > 1.0

    def require_plain(self, source: str, what: str, instead: str) -> None:
        """Refuse a realistic-look dataset where ``what`` reads object-on-black frames only."""
        if self.scene != "plain":
            raise InputError(
                f"a {self.scene}-look dataset: {what} reads the plain look only (the object on "
                f"black, masks by its colour); {instead}",
                source=source,
            )

    def samples_for(self, split: str) -> int:
        return self.samples_per_object if split == "train" else self.test_samples_per_object

    def validated(self) -> DataSettings:
        """Check every value; raises InputError naming the flag."""
        counts = {
            "--objects": (self.objects, 0),
            "--test-objects": (self.test_objects, 0),
            "--samples-per-object": (self.samples_per_object, 1),
            "--test-samples-per-object": (self.test_samples_per_object, 1),
            "--resolution": (self.resolution, 8),
            "--frames": (self.num_frames, 2),
            "--num-gaussians": (self.num_gaussians, 16),
            "--num-anchors": (self.num_anchors, 8),
            "--neighbors": (self.num_neighbors, 1),
            "--min-substeps": (self.min_substeps, 1),
            "--seed": (self.seed, 0),
        }
        for flag, (value, low) in counts.items():
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise InputError(f"must be an integer ≥ {low}, got {value!r}", field=flag)
        if self.objects + self.test_objects < 1:
            raise InputError("ask for at least one object", field="--objects")
        if self.distribution not in DISTRIBUTIONS:
            raise InputError(
                f"expected one of {', '.join(DISTRIBUTIONS)}, got {self.distribution!r}",
                field="--distribution",
            )
        for flag, name in (
            ("--max-horizontal-speed", "max_horizontal_speed"),
            ("--max-angular-speed", "max_angular_speed"),
            ("max_vertical_speed", "max_vertical_speed"),
        ):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise InputError(f"must be a number ≥ 0, got {value!r}", field=flag)
        if not (isinstance(self.toss_fraction, (int, float)) and 0 <= self.toss_fraction <= 1):
            raise InputError(
                f"must be in [0, 1], got {self.toss_fraction!r}", field="--toss-fraction"
            )
        low, high = self.toss_speed_range
        if not (0 < low <= high and math.isfinite(high)):
            raise InputError(f"[{low}, {high}] must satisfy 0 < low ≤ high", "toss_speed_range")
        for name in ("frame_dt", "size", "camera_radius", "camera_fov_deg"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise InputError(f"must be a positive number, got {value!r}", field=name)
        for name, allowed in ATTRIBUTE_RANGES.items():
            low, high = getattr(self, f"{name}_range")
            if not (allowed[0] <= low <= high <= allowed[1]):
                raise InputError(
                    f"[{low}, {high}] must lie inside the range of docs/design.md#attribute-ranges "
                    f"[{allowed[0]}, {allowed[1]}]",
                    field=f"{name}_range",
                )
        if self.scene not in SCENES:
            raise InputError(
                f"expected one of {', '.join(SCENES)}, got {self.scene!r}", field="--scene"
            )
        for name, (lowest, highest) in {
            "object_size_range": (1e-3, 10.0),
            "fov_range_deg": (1.0, 120.0),
            "elevation_range_deg": (0.0, 80.0),
            "framing_range": (0.05, 1.0),
            "noise_range": (0.0, 0.5),
            "video_quality_range": (0.0, 10.0),
        }.items():
            low, high = getattr(self, name)
            if not (lowest <= low <= high <= highest):
                raise InputError(
                    f"[{low}, {high}] must satisfy {lowest} ≤ low ≤ high ≤ {highest}", field=name
                )
        for flag, name in (("--exposure", "exposure_range_s"), ("--readout", "readout_range_s")):
            low, high = getattr(self, name)
            if not (0 <= low <= high <= self.frame_dt):
                raise InputError(
                    f"[{low:g}, {high:g}] s must satisfy 0 ≤ low ≤ high ≤ the frame interval "
                    f"({self.frame_dt:g} s): a sensor exposes and reads once a frame",
                    field=f"{flag} ({name})",
                )
        for name in ("vivid_share", "contrast_share", "hand_share", "grey_share"):
            share = getattr(self, name)
            if not (isinstance(share, (int, float)) and 0 <= share <= 1):
                flag = "--" + name.replace("_", "-")
                raise InputError(f"must be in [0, 1], got {share!r}", field=flag)
        if self.scene == "plain":  # the realistic look's draws, asked of the plain one
            for flag, value in (
                ("--vivid-share", self.vivid_share),
                ("--contrast-share", self.contrast_share),
                ("--hand-share", self.hand_share),
                ("--grey-share", self.grey_share),
                ("--exposure", max(self.exposure_range_s)),
                ("--readout", max(self.readout_range_s)),
            ):
                if value:
                    raise InputError(
                        f"{value:g} asked of the plain look (the object on black): it applies "
                        "to the realistic look only; add --scene realistic",
                        field=flag,
                    )
        first, last = self.contact_frame_range
        if not (0 < first <= last < self.num_frames - 1):
            raise InputError(
                f"[{first}, {last}] must lie inside (0, {self.num_frames - 1})",
                field="contact_frame_range",
            )
        low, high = self.stretch_range
        if not (1.0 <= low <= high <= MAX_STRETCH):
            raise InputError(
                f"[{low}, {high}] must satisfy 1 ≤ low ≤ high ≤ {MAX_STRETCH:g}", field="--stretch"
            )
        low, high = self.drop_height_range
        if not (0 < low <= high):
            raise InputError(f"[{low}, {high}] must satisfy 0 < low ≤ high", "drop_height_range")
        return self


# The presets: settings instances. A config file (``make-data --config``, configs/data_small.toml)
# is applied over the preset, and any flag given on the command line over both.
PRESETS: dict[str, DataSettings] = {
    # CPU-sized: the acceptance run (3 objects × 2 samples at 32 px) takes well under a minute.
    "small": DataSettings(),
    # The paper's protocol (ReconPhys §4.1): 450 × 10 training, 46 × 2 test samples at 512²,
    # with the model defaults of docs/design.md#physical-model (N_A 2048, K 32) and 20 000 Gaussians
    # per object; drops released from rest only (drop, collision, rebound), no tosses.
    "paper": DataSettings(
        objects=450,
        test_objects=46,
        samples_per_object=10,
        test_samples_per_object=2,
        resolution=512,
        num_gaussians=20000,
        num_anchors=2048,
        contact_frame_range=(5.0, 10.0),  # free fall from rest inside drop_height_range
        max_vertical_speed=0.0,
        max_horizontal_speed=0.0,
        max_angular_speed=0.0,
        toss_fraction=0.0,
    ),
}


def make_settings(
    preset: str = "small", config: str | os.PathLike | None = None, **overrides
) -> DataSettings:
    """Settings of ``preset`` ← the config file ``config`` (a table of DataSettings fields,
    type-checked) ← ``overrides`` (``None`` values are ignored), validated."""
    if preset not in PRESETS:
        raise InputError(f"expected one of {', '.join(PRESETS)}, got {preset!r}", field="--preset")
    settings = PRESETS[preset]
    if config is not None:
        settings = load_settings(DataSettings, (read_table(config), str(config)), base=settings)
    values = {k: v for k, v in overrides.items() if v is not None}
    return replace(settings, **values).validated()
