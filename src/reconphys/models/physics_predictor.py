"""Physics predictor (docs/design.md#models, paper §3.3): video frames of one view → (m, k, d, f).

Two inputs (``PredictorConfig.inputs``): ``"video"``, a per-frame encoder → spatio-temporal trunk
(3D residual blocks over [time, height, width], then self-attention over time) → MLP; or
``"track"``, the object's silhouette track alone (:class:`TrackNetwork`: sub-pixel moments per
frame → temporal convolutions) → MLP. Either gives four bounded attributes, one value each per
object.

Bounded outputs: mass, stiffness and damping span one to two orders of magnitude, so they are
mapped log-uniformly into the docs/design.md#attribute-ranges ranges,
``exp(log lo + σ(z) (log hi − log lo))``; friction is ``σ(z)`` in [0, 1].
:func:`normalize_attributes` is the inverse map to [0, 1]⁴, the space of the supervised loss. (The
reference code maps linearly and lets friction reach 2.4; we keep the data's ranges so that every
prediction is a valid, stable simulator input.)

Encoders are looked up by name in :mod:`reconphys.models.encoders`; the default ``small_cnn`` is
trained from scratch. Pretrained encoders (``timm`` by name, ``transformers`` from a local folder
such as InternViT) are in :mod:`reconphys.models.pretrained` and load from local files only.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..capture.calibrate import Z_10_90
from ..physics.model import ATTRIBUTE_RANGES, ATTRIBUTES, observable_bounds
from .encoders import build_encoder, encoder_names, group_norm

LOG_SCALED = ("mass", "stiffness", "damping")


@dataclass
class PredictorConfig:
    encoder: str = "small_cnn"
    encoder_channels: tuple[int, ...] = (32, 64, 128, 128)  # one stride-2 stage each
    token_channels: int = 64  # channels of the spatio-temporal trunk
    trunk_blocks: int = 2  # 3D residual blocks
    attention_heads: int = 4
    mlp_hidden: tuple[int, ...] = (256, 128)
    num_frames: int = 20  # frames the predictor reads (frames 0..num_frames-1)
    resolution: int = 64  # square input size in pixels
    extra: dict = field(default_factory=dict)  # encoder-specific options
    silhouette: bool = False  # add the silhouette-statistics branch (SilhouetteBranch)
    motion: bool = False  # feed the encoder each frame's change too (motion_channels; small_cnn)
    inputs: str = "video"  # "video": the CNN trunk (+ branches above); "track": TrackNetwork alone
    track_channels: int = 64  # inputs = "track": width of the track's temporal convolutions
    crop: bool = False  # read the object's motion-box crop (model_input.object_crop), not the frame
    scale_head: bool = False  # also predict its own error's scale (observable_scale; detached)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> PredictorConfig:
        data = dict(data)
        for key in ("encoder_channels", "mlp_hidden"):
            if key in data:
                data[key] = tuple(data[key])
        return cls(**data)


# --- motion channels ------------------------------------------------------------------------

MOTION_GAIN = 4.0  # sub-pixel motion changes pixels by a few percent: bring it to the frame's scale


def motion_channels(
    frames: Tensor,  # [B, T, H, W, 3] in [0, 1]
) -> Tensor:  # [B, T, H, W, 9]
    """Each frame beside how it changed since the previous frame and since frame 0 (× 4).

    A per-frame encoder that strides down to 4×4 maps keeps little of a sub-pixel slide or a
    squash that decays over a few frames — what friction and damping change. Differencing at full
    resolution before the encoder (a two-stream network's cheap motion stream) hands it those
    changes directly. Frame 0's changes are zero."""
    previous = torch.cat([frames[:, :1], frames[:, :-1]], 1)
    return torch.cat(
        [frames, MOTION_GAIN * (frames - previous), MOTION_GAIN * (frames - frames[:, :1])], -1
    )


# --- trunk ----------------------------------------------------------------------------------


class Residual3d(nn.Module):
    """Bottleneck residual block over [B, C, T, h, w] (1×1×1 → 3×3×3 → 1×1×1)."""

    def __init__(self, channels: int):
        super().__init__()
        inner = max(channels // 2, 8)
        self.body = nn.Sequential(
            nn.Conv3d(channels, inner, 1),
            group_norm(inner),
            nn.SiLU(),
            nn.Conv3d(inner, inner, 3, padding=1),
            group_norm(inner),
            nn.SiLU(),
            nn.Conv3d(inner, channels, 1),
            group_norm(channels),
        )
        self.act = nn.SiLU()

    def forward(self, x: Tensor) -> Tensor:
        return self.act(x + self.body(x))


class TemporalAttention(nn.Module):
    """Pre-norm self-attention over time plus an MLP, on tokens [B, T, C]."""

    def __init__(self, channels: int, heads: int, num_frames: int):
        super().__init__()
        self.position = nn.Parameter(torch.zeros(1, num_frames, channels))
        nn.init.normal_(self.position, std=0.02)
        self.norm1 = nn.LayerNorm(channels)
        self.attention = nn.MultiheadAttention(channels, heads, batch_first=True)
        self.norm2 = nn.LayerNorm(channels)
        self.mlp = nn.Sequential(
            nn.Linear(channels, 2 * channels), nn.GELU(), nn.Linear(2 * channels, channels)
        )

    def forward(self, tokens: Tensor) -> Tensor:
        x = tokens + self.position[:, : tokens.shape[1]]
        h = self.norm1(x)
        x = x + self.attention(h, h, h, need_weights=False)[0]
        return x + self.mlp(self.norm2(x))


# --- silhouette statistics ------------------------------------------------------------------

SILHOUETTE_STATS = 6  # area, centroid x, y, second central moments xx, yy, xy
OBJECT_LEVEL = 0.05  # a pixel whose brightest channel reaches this is all object (black backdrop)


def silhouette_statistics(
    frames: Tensor,  # [B, T, H, W, 3] in [0, 1], the object on a black backdrop
) -> Tensor:  # [B, T, 6]
    """Per frame: the object's area (fraction of the image), centroid (x, y) and second central
    moments (xx, yy, xy), pixel coordinates in [−1, 1] (x right, y down). Each pixel weighs
    ``min(1, brightest channel / 0.05)``, so edge pixels count by their coverage and the centroid
    moves by fractions of a pixel. An empty frame gives zeros."""
    h, w = frames.shape[2:4]
    weight = (frames.amax(-1) / OBJECT_LEVEL).clamp(0, 1)  # [B, T, H, W]
    y = torch.linspace(-1, 1, h, device=frames.device, dtype=frames.dtype)[:, None]
    x = torch.linspace(-1, 1, w, device=frames.device, dtype=frames.dtype)[None, :]
    total = weight.sum((-2, -1))
    safe = total.clamp_min(1e-6)
    cx = (weight * x).sum((-2, -1)) / safe
    cy = (weight * y).sum((-2, -1)) / safe
    dx = x - cx[..., None, None]
    dy = y - cy[..., None, None]
    xx = (weight * dx * dx).sum((-2, -1)) / safe
    yy = (weight * dy * dy).sum((-2, -1)) / safe
    xy = (weight * dx * dy).sum((-2, -1)) / safe
    stats = torch.stack([total / (h * w), cx, cy, xx, yy, xy], -1)
    return stats * (total > 0)[..., None]


def silhouette_motion(
    stats: Tensor,  # [B, T, 6] silhouette_statistics
) -> Tensor:  # [B, T, 12]
    """How the silhouette changes, in units of the object's own size, and how fast: per frame the
    change since frame 0 of the area (relative), the centroid (over the frame-0 radius of
    gyration) and the second moments (relative to frame 0's), then their frame-to-frame
    differences (0 at frame 0). No absolute shape or position: what it shows is motion."""
    area0, xx0, yy0, xy0 = stats[:, :1, 0], stats[:, :1, 3], stats[:, :1, 4], stats[:, :1, 5]
    spread = (xx0 + yy0).clamp_min(1e-6)
    radius = spread.sqrt()
    change = torch.stack(
        [
            stats[..., 0] / area0.clamp_min(1e-6) - 1,
            (stats[..., 1] - stats[:, :1, 1]) / radius,
            (stats[..., 2] - stats[:, :1, 2]) / radius,
            stats[..., 3] / xx0.clamp_min(1e-6) - 1,
            stats[..., 4] / yy0.clamp_min(1e-6) - 1,
            (stats[..., 5] - xy0) / spread,
        ],
        -1,
    ) * (area0[..., None] > 0)
    speed = torch.cat([torch.zeros_like(change[:, :1]), change.diff(dim=1)], 1)
    return torch.cat([change, speed], -1)


class SilhouetteBranch(nn.Module):
    """The silhouette's motion over the video → a vector added to the pooled video features.

    A CNN whose maps are averaged over space and time keeps little of *how far* the object moved
    or *how much* it squashed and for how long: sub-pixel quantities at the 32-px size, yet exactly
    what friction (sliding after contact) and damping (the decay of the squash) change. The branch
    reads :func:`silhouette_motion` (no absolute shape, so it cannot learn objects by heart)
    with two temporal convolutions, pooled by mean and max over time (the contact frame varies
    from video to video), and a linear map to the trunk's width.
    """

    def __init__(self, channels: int, hidden: int = 32):
        super().__init__()
        self.conv = nn.Sequential(
            nn.Conv1d(2 * SILHOUETTE_STATS, hidden, 3, padding=1),
            nn.GELU(),
            nn.Conv1d(hidden, hidden, 3, padding=1),
            nn.GELU(),
        )
        self.out = nn.Linear(2 * hidden, channels)

    def forward(self, frames: Tensor) -> Tensor:  # [B, T, H, W, 3] → [B, channels]
        motion = silhouette_motion(silhouette_statistics(frames)).transpose(1, 2)  # [B, 12, T]
        features = self.conv(motion)
        return self.out(torch.cat([features.mean(-1), features.amax(-1)], -1))


# --- the track network ---------------------------------------------------------------------

INPUTS = ("video", "track")
TRACK_FEATURES = 2 * SILHOUETTE_STATS + SILHOUETTE_STATS  # silhouette_motion + the statistics


def track_features(
    frames: Tensor,  # [B, T, H, W, 3] in [0, 1], the object on a black backdrop
) -> Tensor:  # [B, T, 18]
    """Per frame, the silhouette's motion (:func:`silhouette_motion`: changes since frame 0 in
    units of the object's own size, and their speed) beside its statistics
    (:func:`silhouette_statistics`: area, centroid and second moments in the frame)."""
    stats = silhouette_statistics(frames)
    return torch.cat([silhouette_motion(stats), stats], -1)


class TrackNetwork(nn.Module):
    """The object's silhouette track over the clip → a feature vector (``inputs = "track"``).

    The physical observables are in how the silhouette moves: how far it falls per frame²
    (the scale, since gravity is known), how much and how long it squashes at contact (k/m),
    how fast the squash and the bounce decay (d/m), how far it slides (friction). At 32 px these
    are fractions of a pixel, which :func:`silhouette_statistics` keeps (coverage-weighted
    moments) and a strided CNN averages away. Per-channel normalisation of the features
    (BatchNorm, its running statistics saved with the weights), three temporal convolutions
    pooled by mean and max over time (where contact happens varies), and a linear map of the
    whole normalised track (when it happens matters too). Clips shorter than ``num_frames`` are
    padded with the mean (zeros after normalisation).
    """

    def __init__(self, num_frames: int, channels: int = 64, hidden: int = 128):
        super().__init__()
        self.num_frames = num_frames
        self.norm = nn.BatchNorm1d(TRACK_FEATURES)
        layers, previous = [], TRACK_FEATURES
        for _ in range(3):
            layers += [nn.Conv1d(previous, channels, 3, padding=1), nn.GELU()]
            previous = channels
        self.conv = nn.Sequential(*layers)
        self.whole = nn.Sequential(nn.Linear(TRACK_FEATURES * num_frames, hidden), nn.GELU())
        self.out_channels = 2 * channels + hidden

    def forward(self, frames: Tensor) -> Tensor:  # [B, T, H, W, 3] → [B, out_channels]
        track = self.norm(track_features(frames).transpose(1, 2))  # [B, 18, T]
        track = F.pad(track, (0, self.num_frames - track.shape[-1]))
        features = self.conv(track)
        return torch.cat([features.mean(-1), features.amax(-1), self.whole(track.flatten(1))], -1)


# --- attribute bounds -----------------------------------------------------------------------


def _bounds(name: str) -> tuple[float, float]:
    low, high = ATTRIBUTE_RANGES[name]
    if name in LOG_SCALED:
        return math.log(low), math.log(high)
    return low, high


def attributes_from_unit(unit: Tensor) -> dict[str, Tensor]:
    """[..., 4] in [0, 1] → {mass, stiffness, damping, friction} in the
    docs/design.md#attribute-ranges ranges."""
    out = {}
    for index, name in enumerate(ATTRIBUTES):
        low, high = _bounds(name)
        value = low + unit[..., index] * (high - low)
        out[name] = torch.exp(value) if name in LOG_SCALED else value
    return out


# The network's own belief about each observable: a normal distribution at the ensemble's mean
# answer, σ = a × the members' standard deviation (observable_spread), per observable (log k/m,
# log d/m, f). The seeds' spread tracks the error only loosely (rank correlation 0.1–0.3) and is too
# narrow by itself (its ±1.28 σ held the truth on 21–40 %), so a is calibrated for each ensemble on
# validation meshes only (never a test split; benchmarks/network_intervals.py) as the factors that
# keep the coverages measured there inside 70–90 %, and stored in its JSON as "spread_factor"
# (docs/usage.md "The network's belief and the recording's"). An ensemble without one gets this
# default, the factors of the network of object crops (82 / 80 / 88 % on 200 realistic validation
# drops and tosses, segmenter masks).
DEFAULT_SPREAD_FACTOR = (3.0, 3.0, 4.0)


def observable_spread(member_unit: Tensor) -> Tensor:
    """An ensemble's members' unit outputs [M, B, 4] (M ≥ 2) → [B, 3] their standard deviation
    (unbiased) of log k/m, log d/m (natural logs of the SI ratios) and friction: how much the
    seeds disagree, the raw material of the network's own interval (× the ensemble's
    ``spread_factor``, ``DEFAULT_SPREAD_FACTOR``)."""
    if member_unit.dim() != 3 or member_unit.shape[0] < 2 or member_unit.shape[-1] != 4:
        raise ValueError(f"member_unit: expected [M ≥ 2, B, 4], got {list(member_unit.shape)}")
    a = attributes_from_unit(member_unit.double())
    values = torch.stack(
        [(a["stiffness"] / a["mass"]).log(), (a["damping"] / a["mass"]).log(), a["friction"]], -1
    )
    return values.std(0)


# What an ensemble with a scale head (PredictorConfig.scale_head) gets without its own factors:
# the scale is the error's own estimate, trained for it, not a spread that needs stretching.
SCALE_HEAD_SPREAD_FACTOR = (1.0, 1.0, 1.0)
LN5 = math.log(5.0)  # a Laplace's 10–90 % interval: its centre ± ln 5 · b


def network_sigma(out: dict[str, Tensor], factor: tuple[float, float, float]) -> Tensor | None:
    """σ [B, 3] of the network's normal belief about log k/m, log d/m and f from its output:
    ``factor`` × √(spread² + (ln 5 · b / z)²), the members' spread (:func:`observable_spread`;
    an ensemble) and the scale head's Laplace scale b as the normal whose 10–90 % interval has
    the same width (z = 1.2816; ``observable_scale``), whichever the output holds. None when it
    holds neither (a single network without a scale head: no belief)."""
    parts = []
    if "member_unit" in out:
        parts.append(observable_spread(out["member_unit"].double()))
    if "observable_scale" in out:
        parts.append(LN5 * out["observable_scale"].double() / Z_10_90)
    if not parts:
        return None
    combined = parts[0] if len(parts) == 1 else torch.stack(parts).square().sum(0).sqrt()
    return torch.tensor(factor, dtype=combined.dtype, device=combined.device) * combined


def normalize_attributes(attributes: dict[str, Tensor] | Tensor) -> Tensor:
    """Inverse of :func:`attributes_from_unit`: attributes (dict, or [..., 4] in
    ATTRIBUTES) → [..., 4] in [0, 1] (clamped)."""
    if isinstance(attributes, Tensor):
        attributes = {n: attributes[..., i] for i, n in enumerate(ATTRIBUTES)}
    columns = []
    for name in ATTRIBUTES:
        low, high = _bounds(name)
        value = attributes[name]
        value = torch.log(value) if name in LOG_SCALED else value
        columns.append(((value - low) / (high - low)).clamp(0.0, 1.0))
    return torch.stack(columns, -1)


def resize_frames(frames: Tensor, resolution: int) -> Tensor:
    """Frames at the predictor's input size: [B, T, H, W, 3] → [B, T, R, R, 3], R = resolution
    (area average down, bilinear up; the dataset resizes the same way)."""
    b, t, h, w, _ = frames.shape
    if h == resolution and w == resolution:
        return frames
    flat = frames.reshape(b * t, h, w, 3).permute(0, 3, 1, 2)
    if resolution < h:
        flat = F.interpolate(flat, size=(resolution, resolution), mode="area")
    else:
        flat = F.interpolate(flat, size=(resolution, resolution), mode="bilinear")
    return flat.permute(0, 2, 3, 1).reshape(b, t, resolution, resolution, 3).clamp(0, 1)


# --- the predictor --------------------------------------------------------------------------


def _mlp_head(
    channels: int, hidden: tuple[int, ...], outputs: int = len(ATTRIBUTES)
) -> nn.Sequential:
    """Features [B, channels] → logits [B, outputs] (GELU MLP; four: the attributes)."""
    layers, previous = [], channels
    for width in hidden:
        layers += [nn.Linear(previous, width), nn.GELU()]
        previous = width
    layers.append(nn.Linear(previous, outputs))
    return nn.Sequential(*layers)


# The scale head's floor, in the observables' [0, 1] units: keeps log b finite.
MIN_SCALE = 1e-3


def observable_scale(logits: Tensor) -> Tensor:
    """The scale head's logits [..., 3] → the expected |error| of the answer's log k/m, log d/m
    and friction [..., 3] in their natural units (a Laplace scale b: its 10–90 % interval is the
    answer ± ln 5 · b), through softplus in the observables' [0, 1] units."""
    bounds = observable_bounds().to(logits.dtype).to(logits.device)
    return (F.softplus(logits) + MIN_SCALE) * (bounds[:, 1] - bounds[:, 0])


class PhysicsPredictor(nn.Module):
    def __init__(self, config: PredictorConfig | None = None):
        super().__init__()
        self.config = config = config or PredictorConfig()
        if config.inputs not in INPUTS:
            raise ValueError(f"inputs: expected one of {INPUTS}, got {config.inputs!r}")
        if config.inputs == "track":
            self.track = TrackNetwork(config.num_frames, config.track_channels)
            self.head = _mlp_head(self.track.out_channels, config.mlp_hidden)
            self.scale = self._scale_head(self.track.out_channels)
            return
        self.track = None
        if config.encoder not in encoder_names():
            raise ValueError(f"encoder: unknown {config.encoder!r}; known: {encoder_names()}")
        if config.motion and config.encoder != "small_cnn":
            raise ValueError(
                f"motion: only the small_cnn encoder reads motion channels, got {config.encoder!r}"
            )
        self.encoder = build_encoder(config)
        c = config.token_channels
        self.project = nn.Conv3d(self.encoder.out_channels, c, 1)
        self.trunk = nn.Sequential(*[Residual3d(c) for _ in range(config.trunk_blocks)])
        self.temporal = TemporalAttention(c, config.attention_heads, config.num_frames)
        self.silhouette = SilhouetteBranch(c) if config.silhouette else None
        self.head = _mlp_head(c, config.mlp_hidden)
        self.scale = self._scale_head(c)

    def _scale_head(self, channels: int) -> nn.Sequential | None:
        """Built last, so a config with it initialises every other weight as one without."""
        if not self.config.scale_head:
            return None
        return _mlp_head(channels, self.config.mlp_hidden, outputs=3)

    def _outputs(self, features: Tensor) -> dict[str, Tensor]:
        """Features [B, C] → the answer, and the scale of its error when the config has one
        (read from the features detached: it never changes what the answer learns)."""
        unit = torch.sigmoid(self.head(features))
        out = {"unit": unit, **attributes_from_unit(unit)}
        if self.scale is not None:
            out["observable_scale"] = observable_scale(self.scale(features.detach()))
        return out

    def forward(self, frames: Tensor) -> dict[str, Tensor]:
        """frames [B, T, H, W, 3] in [0, 1] (one view; T ≤ num_frames, H = W = resolution) →
        {"unit": [B, 4] in (0, 1), "mass", "stiffness", "damping", "friction": [B]}, and with
        ``scale_head`` "observable_scale" [B, 3] (:func:`observable_scale`)."""
        if frames.dim() != 5 or frames.shape[-1] != 3:
            raise ValueError(f"frames: expected [B, T, H, W, 3], got {list(frames.shape)}")
        b, t, h, w, _ = frames.shape
        if t > self.config.num_frames:
            raise ValueError(f"frames: at most {self.config.num_frames} frames, got {t}")
        if self.track is not None:
            return self._outputs(self.track(frames))
        pixels = motion_channels(frames) if self.config.motion else frames
        images = pixels.reshape(b * t, h, w, pixels.shape[-1]).permute(0, 3, 1, 2)
        features = self.encoder(images)  # [B·T, C, h', w']
        features = features.reshape(b, t, *features.shape[1:]).transpose(1, 2)  # [B, C, T, h', w']
        tokens = self.trunk(self.project(features)).mean((-2, -1)).transpose(1, 2)  # [B, T, C]
        pooled = self.temporal(tokens).mean(1)
        if self.silhouette is not None:
            pooled = pooled + self.silhouette(frames)
        return self._outputs(pooled)


class PredictorEnsemble(nn.Module):
    """Members of one config trained from different seeds; their answer is the mean of the
    members' unit outputs, i.e. of log m, log k, log d and f — so also of log k/m and log d/m.

    Seeds disagree most where the training data does not pin the answer down, and averaging
    removes that part of each member's error (docs/training.md "An ensemble of seeds")."""

    def __init__(self, config: PredictorConfig, members: int):
        super().__init__()
        if members < 2:
            raise ValueError(f"members: an ensemble needs at least 2, got {members}")
        self.members = nn.ModuleList(PhysicsPredictor(config) for _ in range(members))

    @property
    def config(self) -> PredictorConfig:
        return self.members[0].config

    def forward(self, frames: Tensor) -> dict[str, Tensor]:
        """As :meth:`PhysicsPredictor.forward`, plus "member_unit": [M, B, 4] each member's;
        with ``scale_head``, "observable_scale" is the members' mean scale [B, 3]."""
        outs = [member(frames) for member in self.members]
        units = torch.stack([out["unit"] for out in outs])  # [M, B, 4]
        unit = units.mean(0)
        result = {"unit": unit, **attributes_from_unit(unit), "member_unit": units}
        if "observable_scale" in outs[0]:
            result["observable_scale"] = torch.stack([o["observable_scale"] for o in outs]).mean(0)
        return result
