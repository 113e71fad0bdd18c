"""The ``realistic`` look (docs/design.md#synthetic-dataset): the object in a scene as filmed.

A textured ground plane z = 0, a backdrop at infinity (an environment: horizon-to-zenith gradient
with vertical bands, like walls and furniture seen from afar), a directional light that shades the
object and casts a soft shadow on the ground, and sensor noise. The scene is drawn analytically per
pixel (a ray–plane intersection), so it needs no mesh; the object is the usual Gaussian render,
composited over it (``rgb + (1 − alpha) · scene``, the renderer's colour being premultiplied).

Object shading uses radial normals (from the object's current centroid to each Gaussian): no
normals are stored with Gaussians, and radial ones turn with the object as it tumbles. The
shadow is a splat of the anchors projected along the light onto the ground, softer and fainter the
higher they are; it is an appearance cue, not a physical light transport.
"""

from __future__ import annotations

import colorsys
import math
from dataclasses import asdict, dataclass, replace

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from ..assets.gaussians import SH_C0, Gaussians
from .cameras import Cameras

GROUND_PATTERNS = ("checker", "stripes", "tiles", "noise")
# the vivid look's (vivid_look): also "patches", blobs of three to five colours (a play mat, a rug)
VIVID_GROUND_PATTERNS = (*GROUND_PATTERNS, "patches")
OBJECT_PATTERNS = ("none", "checker", "stripes", "patches")  # printed on the object (vivid)
# the high-contrast look's floors (contrast_look): a simulator's checker floor or tiles, dark and
# bright, or blobs of the two (drawn with these weights)
CONTRAST_GROUND_PATTERNS = {"checker": 0.6, "tiles": 0.2, "patches": 0.2}
NOISE_GRID = 16  # cells of the periodic value-noise textures
FOG_DISTANCE = 12.0  # metres: the ground fades into the horizon colour beyond this
SHADOW_GRID = 64  # cells per side of the shadow map around the object's footprint


@dataclass(frozen=True)
class SceneLook:
    """Everything random about one scene (colours RGB in [0, 1], lengths in metres)."""

    ground_pattern: str  # one of VIVID_GROUND_PATTERNS
    ground_colors: tuple[tuple[float, float, float], ...]  # two; "patches": three to five
    ground_period: float  # metres per pattern repeat
    ground_angle: float  # radians: the pattern's rotation about z
    horizon_color: tuple[float, float, float]
    zenith_color: tuple[float, float, float]
    band_contrast: float  # in [0, 1): strength of the backdrop's vertical bands
    light_direction: tuple[float, float, float]  # unit vector towards the light, z > 0
    ambient: float  # share of the light that is not direct (fills shadows)
    noise_sigma: float  # sensor noise, standard deviation in [0, 1] colour units
    texture_seed: int
    # a pattern printed on the object (OBJECT_PATTERNS; vivid_look), in its frame-0 coordinates:
    # colours mixed into the Gaussians' own by ``object_mix``, ``object_period`` metres a repeat
    object_pattern: str = "none"
    object_colors: tuple[tuple[float, float, float], ...] = ()
    object_period: float = 0.1
    object_mix: float = 0.0
    # the object's colours mixed towards their grey (grey_look): 1 keeps them, 0 is all grey
    object_saturation: float = 1.0
    # the grey object's mean grey moved to this (grey_look: white to black); None keeps its own
    object_lightness: float | None = None

    def to_dict(self) -> dict:  # JSON-ready (tuples are written as lists)
        return asdict(self)


def draw_look(rng: np.random.Generator, noise_range: tuple[float, float]) -> SceneLook:
    """A random scene: muted ground colours (floors are rarely saturated), a backdrop that is
    brighter towards the zenith, a light 30–70° above the horizon from any side."""

    def colour(low: float, high: float, saturation: float) -> tuple[float, float, float]:
        grey = rng.uniform(low, high)
        tint = rng.uniform(-saturation, saturation, 3)
        return tuple(float(np.clip(grey + t, 0.0, 1.0)) for t in tint)

    base = colour(0.15, 0.75, 0.12)
    second = tuple(float(np.clip(c * rng.uniform(0.5, 0.85), 0, 1)) for c in base)
    elevation = rng.uniform(math.radians(30), math.radians(70))
    azimuth = rng.uniform(0, 2 * math.pi)
    light = (
        math.cos(elevation) * math.cos(azimuth),
        math.cos(elevation) * math.sin(azimuth),
        math.sin(elevation),
    )
    return SceneLook(
        ground_pattern=str(rng.choice(GROUND_PATTERNS)),
        ground_colors=(base, second),
        ground_period=float(rng.uniform(0.1, 0.6)),
        ground_angle=float(rng.uniform(0, math.pi)),
        horizon_color=colour(0.3, 0.85, 0.15),
        zenith_color=colour(0.5, 0.95, 0.1),
        band_contrast=float(rng.uniform(0.0, 0.5)),
        light_direction=light,
        ambient=float(rng.uniform(0.35, 0.7)),
        noise_sigma=float(rng.uniform(*noise_range)),
        texture_seed=int(rng.integers(0, 2**31 - 1)),
    )


def vivid_look(rng: np.random.Generator, look: SceneLook, size: float) -> SceneLook:
    """``look`` made vivid (the scenes a muted look never shows: a play mat, a painted wall, a
    printed toy): saturated ground colours, unrelated to each other, in any of
    VIVID_GROUND_PATTERNS; a saturated backdrop with strong bands; a pattern printed on the
    object (largest side ``size`` metres) on three in four. Light, noise and texture seed stay."""

    def saturated() -> tuple[float, float, float]:
        hue, saturation, value = rng.uniform(), rng.uniform(0.35, 1.0), rng.uniform(0.3, 1.0)
        return colorsys.hsv_to_rgb(float(hue), float(saturation), float(value))

    pattern = str(rng.choice(VIVID_GROUND_PATTERNS))
    count = int(rng.integers(3, 6)) if pattern == "patches" else 2
    printed = str(rng.choice(OBJECT_PATTERNS[1:])) if rng.random() < 0.75 else "none"
    return replace(
        look,
        ground_pattern=pattern,
        ground_colors=tuple(saturated() for _ in range(count)),
        horizon_color=saturated(),
        zenith_color=saturated(),
        band_contrast=float(rng.uniform(0.3, 0.9)),
        object_pattern=printed,
        object_colors=tuple(saturated() for _ in range(int(rng.integers(2, 4)))),
        object_period=float(size * rng.uniform(0.15, 0.6)),
        object_mix=float(rng.uniform(0.5, 1.0)),
    )


def contrast_look(rng: np.random.Generator, look: SceneLook) -> SceneLook:
    """``look`` with a high-contrast floor (what an engine's default scene shows: a checker floor
    of a dark and a bright colour, several times the muted look's contrast): one colour of value
    0–0.25, the other 0.6–1, each of any hue, at most half-saturated when bright, in one of
    CONTRAST_GROUND_PATTERNS. The rest of the scene stays."""

    def hsv(value: tuple[float, float], saturation: float) -> tuple[float, float, float]:
        hue, sat, val = rng.uniform(), rng.uniform(0.0, saturation), rng.uniform(*value)
        return colorsys.hsv_to_rgb(float(hue), float(sat), float(val))

    names, weights = zip(*CONTRAST_GROUND_PATTERNS.items(), strict=True)
    pattern = str(rng.choice(names, p=np.array(weights) / sum(weights)))
    colours = [hsv((0.0, 0.25), 1.0), hsv((0.6, 1.0), 0.5)]
    if rng.random() < 0.5:
        colours.reverse()
    return replace(look, ground_pattern=pattern, ground_colors=tuple(colours))


# A grey object's colours keep at most this share of their difference from their grey
GREY_MAX_SATURATION = 0.15
# and its mean grey is drawn from this range: black to white plastic (the meshes' textures are
# mostly mid to dark, 0.2–0.5; a white object was missed whole by a segmenter that had seen none)
GREY_LIGHTNESS_RANGE = (0.05, 0.95)


def grey_look(rng: np.random.Generator, look: SceneLook) -> SceneLook:
    """``look`` with a grey object (grey, white or black plastic and metal, which the meshes'
    textures never show): its colours keep 0–GREY_MAX_SATURATION of their saturation, their
    mean grey drawn from GREY_LIGHTNESS_RANGE. The rest of the scene stays."""
    saturation = float(rng.uniform(0.0, GREY_MAX_SATURATION))
    lightness = float(rng.uniform(*GREY_LIGHTNESS_RANGE))
    return replace(look, object_saturation=saturation, object_lightness=lightness)


def grey_colours(colours: Tensor, look: SceneLook) -> Tensor:  # [N, 3] → [N, 3] in [0, 1]
    """Colours mixed towards their grey (the mean of r, g, b) by ``look.object_saturation``,
    then shifted so that their mean grey is ``look.object_lightness`` (where given; clipped to
    [0, 1], so a texture's pattern survives but for its extremes)."""
    if look.object_saturation == 1.0 and look.object_lightness is None:
        return colours
    grey = colours.mean(-1, keepdim=True)
    mixed = grey + look.object_saturation * (colours - grey)
    if look.object_lightness is None:
        return mixed
    return (mixed + (look.object_lightness - grey.mean())).clamp(0.0, 1.0)


def _palette(blend: Tensor, colours: Tensor) -> Tensor:
    """Blend [...] in [0, 1] → the colour [..., 3] of its band among ``colours`` [K, 3]."""
    index = (blend * colours.shape[0]).long().clamp(0, colours.shape[0] - 1)
    return colours[index]


def print_pattern(
    colours: Tensor,  # [N, 3] the Gaussians' colours in [0, 1]
    points: Tensor,  # [N, 3] their frame-0 positions, metres
    look: SceneLook,
    generator: torch.Generator,
) -> Tensor:  # [N, 3]
    """The object's colours with ``look``'s printed pattern (none: unchanged)."""
    if look.object_pattern == "none":
        return colours
    local = (points - points.mean(0)) / look.object_period
    palette = torch.tensor(look.object_colors, dtype=colours.dtype)
    if look.object_pattern == "checker":
        blend = (torch.floor(local).sum(-1) % 2) / 2 + 0.25
    elif look.object_pattern == "stripes":
        blend = torch.frac(local[:, 0] + 0.5 * local[:, 1]) * 0.999
    else:  # "patches": 3-D value noise, as two 2-D ones
        grid = torch.rand(NOISE_GRID, NOISE_GRID, generator=generator, dtype=colours.dtype)
        blend = 0.5 * (
            _value_noise(local[:, 0], local[:, 1], grid)
            + _value_noise(local[:, 2] + 7.0, local[:, 0], grid)
        )
    return (1 - look.object_mix) * colours + look.object_mix * _palette(blend, palette)


def _value_noise(u: Tensor, v: Tensor, grid: Tensor) -> Tensor:
    """Periodic bilinear value noise: coordinates [...] in grid cells, grid [G, G] → [...]."""
    size = grid.shape[0]
    u0, v0 = torch.floor(u), torch.floor(v)
    fu, fv = u - u0, v - v0
    fu, fv = fu * fu * (3 - 2 * fu), fv * fv * (3 - 2 * fv)  # smoothstep: no grid lines
    i0, j0 = u0.long() % size, v0.long() % size
    i1, j1 = (i0 + 1) % size, (j0 + 1) % size
    top = grid[i0, j0] * (1 - fu) + grid[i1, j0] * fu
    bottom = grid[i0, j1] * (1 - fu) + grid[i1, j1] * fu
    return top * (1 - fv) + bottom * fv


def _ground_albedo(xy: Tensor, look: SceneLook, generator: torch.Generator) -> Tensor:
    """Ground colour at world points xy [..., 2] → [..., 3]."""
    c, s = math.cos(look.ground_angle), math.sin(look.ground_angle)
    u = (c * xy[..., 0] + s * xy[..., 1]) / look.ground_period
    v = (-s * xy[..., 0] + c * xy[..., 1]) / look.ground_period
    grid = torch.rand(NOISE_GRID, NOISE_GRID, generator=generator, dtype=xy.dtype)
    grain = _value_noise(u * 4, v * 4, grid)  # fine grain on every pattern
    if look.ground_pattern == "checker":
        blend = ((torch.floor(u) + torch.floor(v)) % 2).to(xy.dtype)
    elif look.ground_pattern == "stripes":  # planks: stripes with a grain along them
        blend = 0.5 + 0.5 * torch.sin(2 * math.pi * u) * (0.6 + 0.4 * grain)
    elif look.ground_pattern == "tiles":  # tiles with dark grout lines
        fu, fv = u - torch.floor(u), v - torch.floor(v)
        grout = (fu < 0.06) | (fv < 0.06)
        blend = torch.where(grout, torch.ones_like(u), 0.3 * grain)
    elif look.ground_pattern == "patches":
        blend = _value_noise(u, v, grid)
        colours = torch.tensor(look.ground_colors, dtype=xy.dtype)
        return _palette(blend, colours) * (0.9 + 0.1 * grain[..., None])
    else:  # "noise": concrete, carpet
        blend = _value_noise(u, v, grid)
    blend = (0.85 * blend + 0.15 * grain).clamp(0, 1)[..., None]
    first = torch.tensor(look.ground_colors[0], dtype=xy.dtype)
    second = torch.tensor(look.ground_colors[1], dtype=xy.dtype)
    return first * (1 - blend) + second * blend


def _backdrop(direction: Tensor, look: SceneLook, generator: torch.Generator) -> Tensor:
    """Colour of the environment seen along unit directions [..., 3] → [..., 3]."""
    elevation = torch.asin(direction[..., 2].clamp(-1, 1))
    azimuth = torch.atan2(direction[..., 1], direction[..., 0])
    t = (elevation / (math.pi / 3)).clamp(0, 1)[..., None]
    horizon = torch.tensor(look.horizon_color, dtype=direction.dtype)
    zenith = torch.tensor(look.zenith_color, dtype=direction.dtype)
    grid = torch.rand(NOISE_GRID, NOISE_GRID, generator=generator, dtype=direction.dtype)
    bands = _value_noise(azimuth / (2 * math.pi) * NOISE_GRID, torch.zeros_like(azimuth), grid)
    shade = 1 - look.band_contrast * bands[..., None] * (1 - t)
    return (horizon * (1 - t) + zenith * t) * shade


def pixel_rays(cameras: Cameras, supersample: int = 1) -> tuple[Tensor, Tensor]:
    """World-frame origins [C, 3] and unit directions [C, H·s, W·s, 3] of the pixels' rays
    (pixel centres at u + 0.5; ``supersample`` s rays per pixel side)."""
    s = supersample
    dtype = torch.float64
    u = (torch.arange(cameras.width * s, dtype=dtype) + 0.5) / s
    v = (torch.arange(cameras.height * s, dtype=dtype) + 0.5) / s
    grid_v, grid_u = torch.meshgrid(v, u, indexing="ij")
    pixels = torch.stack([grid_u, grid_v, torch.ones_like(grid_u)], -1)  # [H, W, 3]
    K = cameras.K.to(dtype)
    world_to_cam = cameras.world_to_cam.to(dtype)
    rotation = world_to_cam[..., :3, :3]  # [C, 3, 3]
    origins = -(rotation.transpose(-1, -2) @ world_to_cam[..., :3, 3:])[..., 0]  # [C, 3]
    in_camera = torch.einsum("cij,hwj->chwi", torch.linalg.inv(K), pixels)
    directions = torch.einsum("cji,chwj->chwi", rotation, in_camera)
    return origins, directions / directions.norm(dim=-1, keepdim=True)


@dataclass
class SceneBackground:
    """The empty scene seen by C cameras (supersampled and averaged to the image size)."""

    ground_direct: Tensor  # [C, H·s, W·s, 3] the ground's colour from the direct light (0 off it)
    ground_xy: Tensor  # [C, H·s, W·s, 2] world xy of each ground ray's hit (0 off the ground)
    on_ground: Tensor  # [C, H·s, W·s] bool
    backdrop: Tensor  # [C, H, W, 3] the lit empty scene, no shadow
    supersample: int


def scene_background(cameras: Cameras, look: SceneLook, supersample: int = 2) -> SceneBackground:
    """The lit empty scene for every camera (no batch dims)."""
    generator = torch.Generator().manual_seed(look.texture_seed)
    origins, directions = pixel_rays(cameras, supersample)
    oz = origins[:, 2, None, None]
    dz = directions[..., 2]
    t = torch.where(dz < -1e-9, -oz / dz.clamp(max=-1e-9), torch.full_like(dz, math.inf))
    on_ground = torch.isfinite(t)
    hit = origins[:, None, None, :2] + t.nan_to_num(0, posinf=0)[..., None] * directions[..., :2]
    ground = _ground_albedo(hit, look, generator)
    sky = _backdrop(directions, look, torch.Generator().manual_seed(look.texture_seed + 1))
    fog = torch.exp(-t.nan_to_num(0, posinf=1e9) / FOG_DISTANCE)[..., None]
    horizon = torch.tensor(look.horizon_color, dtype=ground.dtype)
    light_z = look.light_direction[2]
    ground_lit = ground * (look.ambient + (1 - look.ambient) * light_z)
    ground_lit = ground_lit * fog + horizon * (1 - fog)
    lit = torch.where(on_ground[..., None], ground_lit, sky)
    direct = ground * (1 - look.ambient) * light_z * fog
    return SceneBackground(
        ground_direct=torch.where(on_ground[..., None], direct, torch.zeros_like(direct)),
        ground_xy=torch.where(on_ground[..., None], hit, torch.zeros_like(hit)),
        on_ground=on_ground,
        backdrop=_downsample(lit, supersample),
        supersample=supersample,
    )


def _downsample(images: Tensor, factor: int) -> Tensor:  # [..., H·f, W·f, ch] → [..., H, W, ch]
    if factor == 1:
        return images
    *lead, hf, wf, ch = images.shape
    blocks = images.reshape(*lead, hf // factor, factor, wf // factor, factor, ch)
    return blocks.mean(dim=(-4, -2))


def shadow_cover(
    points: Tensor,  # [P, 3] occluders (e.g. anchors) at one instant, metres
    ground_xy: Tensor,  # [..., 2] ground points, metres
    light_direction: tuple[float, float, float],
    spacing: float,  # typical distance between neighbouring points, metres
    grid: int = SHADOW_GRID,
) -> Tensor:  # [...] share of the direct light blocked, in [0, 1)
    """Soft shadow of a point cloud: each point, projected along the light onto z = 0, blocks a
    Gaussian footprint of width ``spacing/2 + 0.15·height`` whose weight falls as the footprint
    widens (a lifted object casts a fainter, blurrier shadow); the cover saturates as
    ``1 − exp(−Σ)``. It is evaluated on a ``grid``² map over the footprints (±3 widths) and read
    bilinearly at ``ground_xy`` (zero outside the map)."""
    dtype = ground_xy.dtype
    light = torch.tensor(light_direction, dtype=dtype)
    height = points[:, 2].to(dtype).clamp_min(0)
    foot = points[:, :2].to(dtype) - height[:, None] * light[:2] / light[2]  # [P, 2]
    sigma = 0.5 * spacing + 0.15 * height  # [P]
    weight = (0.5 * spacing / sigma) ** 2
    lower = (foot - 3 * sigma[:, None]).amin(0)
    upper = (foot + 3 * sigma[:, None]).amax(0)
    axes = [torch.linspace(float(lower[i]), float(upper[i]), grid, dtype=dtype) for i in (0, 1)]
    cells = torch.stack(torch.meshgrid(*axes, indexing="xy"), -1).reshape(-1, 2)  # [G·G, 2]
    d2 = torch.cdist(cells, foot).square()
    total = (weight * torch.exp(-0.5 * d2 / sigma.square())).sum(-1)
    cover = (1 - torch.exp(-total)).reshape(1, 1, grid, grid)  # rows: y, columns: x
    where = 2 * (ground_xy.reshape(1, 1, -1, 2) - lower) / (upper - lower) - 1
    read = F.grid_sample(cover, where, mode="bilinear", padding_mode="zeros", align_corners=True)
    return read.reshape(ground_xy.shape[:-1])


def shade_gaussians(gaussians: Gaussians, look: SceneLook) -> Gaussians:
    """Lambertian shading of the Gaussians' colours by the look's light, with radial normals
    (from the centroid of the means [..., N, 3] of each set)."""
    means = gaussians.means
    normals = means - means.mean(dim=-2, keepdim=True)
    normals = normals / normals.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    light = torch.tensor(look.light_direction, dtype=means.dtype, device=means.device)
    lambert = (normals @ light).clamp_min(0)[..., None]
    factor = look.ambient + (1 - look.ambient) * lambert
    colors = gaussians.colors * factor
    return Gaussians(
        means=means,
        quats=gaussians.quats,
        log_scales=gaussians.log_scales,
        opacity_logits=gaussians.opacity_logits,
        sh0=(colors - 0.5) / SH_C0,
    )


def composite_in_scene(
    rgb: Tensor,  # [C, T, H, W, 3] premultiplied object colour (already shaded)
    alpha: Tensor,  # [C, T, H, W]
    occluders: Tensor,  # [T, P, 3] shadow-casting points per frame, metres
    background: SceneBackground,
    look: SceneLook,
    spacing: float,  # metres between neighbouring occluders
) -> Tensor:  # [C, T, H, W, 3] in [0, 1]
    """The object over the scene, with its shadow darkening the ground's direct light."""
    s = background.supersample
    frames = []
    for t in range(rgb.shape[1]):
        cover = torch.zeros(background.on_ground.shape, dtype=torch.float64)
        where = background.on_ground
        cover[where] = shadow_cover(
            occluders[t].double(), background.ground_xy[where], look.light_direction, spacing
        )
        darkening = _downsample(background.ground_direct * cover[..., None], s)
        scene = (background.backdrop - darkening).clamp(0, 1).to(rgb.dtype)
        frames.append(rgb[:, t] + (1 - alpha[:, t, ..., None]) * scene)
    return torch.stack(frames, 1).clamp(0, 1)


def add_sensor_noise(frames: Tensor, sigma: float, seed: int) -> Tensor:
    """Gaussian read noise of standard deviation ``sigma`` on [..., 3] frames in [0, 1]."""
    if sigma <= 0:
        return frames
    generator = torch.Generator().manual_seed(seed)
    noise = torch.randn(frames.shape, generator=generator, dtype=frames.dtype)
    return (frames + sigma * noise).clamp(0, 1)
