"""The realistic look's scene (render/scene.py): rays, the ground, the shadow, shading, noise and
compression, each checked against an independent computation (forward projection, the shadow's
analytic footprint, Lambert's law, PSNR)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from reconphys.assets.gaussians import Gaussians
from reconphys.render import dataset_views
from reconphys.render.scene import (
    CONTRAST_GROUND_PATTERNS,
    OBJECT_PATTERNS,
    VIVID_GROUND_PATTERNS,
    add_sensor_noise,
    composite_in_scene,
    contrast_look,
    draw_look,
    pixel_rays,
    print_pattern,
    scene_background,
    shade_gaussians,
    shadow_cover,
    vivid_look,
)
from reconphys.render.video import compress_video


def look(**changes):
    base = draw_look(np.random.default_rng(0), (0.0, 0.0))
    return base if not changes else type(base)(**{**base.__dict__, **changes})


def test_each_ray_passes_through_the_point_that_projects_onto_its_pixel():
    cameras = dataset_views(12, 10, elevation_deg=25.0, dtype=torch.float64)
    origins, directions = pixel_rays(cameras)
    assert torch.allclose(origins, cameras.centers)
    depth = 1.7
    points = origins[:, None, None] + depth * directions  # [C, H, W, 3]
    rotation, translation = cameras.world_to_cam[:, :3, :3], cameras.world_to_cam[:, :3, 3]
    in_camera = torch.einsum("cij,chwj->chwi", rotation, points) + translation[:, None, None]
    uv = torch.einsum("cij,chwj->chwi", cameras.K, in_camera)
    uv = uv[..., :2] / uv[..., 2:]
    u = torch.arange(12, dtype=torch.float64) + 0.5
    v = torch.arange(10, dtype=torch.float64) + 0.5
    assert torch.allclose(uv[..., 0], u.expand(4, 10, 12), atol=1e-9)
    assert torch.allclose(uv[..., 1], v[:, None].expand(4, 10, 12), atol=1e-9)


def test_ground_hits_lie_on_their_pixels_and_the_sky_is_above_the_horizon():
    cameras = dataset_views(16, 16, elevation_deg=10.0, fov_deg=60.0, dtype=torch.float64)
    background = scene_background(cameras, look(), supersample=1)
    hits = torch.cat([background.ground_xy, torch.zeros_like(background.ground_xy[..., :1])], -1)
    rotation, translation = cameras.world_to_cam[:, :3, :3], cameras.world_to_cam[:, :3, 3]
    in_camera = torch.einsum("cij,chwj->chwi", rotation, hits) + translation[:, None, None]
    uv = torch.einsum("cij,chwj->chwi", cameras.K, in_camera)
    uv = uv[..., :2] / uv[..., 2:]
    ground = background.on_ground
    columns = (torch.arange(16, dtype=torch.float64) + 0.5).expand(4, 16, 16)
    rows = (torch.arange(16, dtype=torch.float64) + 0.5)[:, None].expand(4, 16, 16)
    assert torch.allclose(uv[..., 0][ground], columns[ground], atol=1e-6)
    assert torch.allclose(uv[..., 1][ground], rows[ground], atol=1e-6)
    # a camera 10° above its target, with a 60° field of view, sees ground in its lower half
    # and sky in its top rows
    assert bool(ground[:, -1].all()) and not bool(ground[:, 0].any())
    assert background.backdrop.shape == (4, 16, 16, 3)
    assert float(background.backdrop.min()) >= 0 and float(background.backdrop.max()) <= 1


@pytest.mark.parametrize("pattern", VIVID_GROUND_PATTERNS)
def test_every_ground_pattern_is_textured(pattern):
    cameras = dataset_views(32, 32, elevation_deg=40.0, dtype=torch.float64)
    background = scene_background(cameras, look(ground_pattern=pattern, ground_period=0.2))
    ground = background.backdrop[0][-8:]  # the bottom rows: near ground
    assert float(ground.std(dim=(0, 1)).max()) > 0.01  # a texture, not a flat colour


def test_shadow_sits_where_the_light_projects_the_object_and_fades_as_it_rises():
    light = (0.3, -0.2, math.sqrt(1 - 0.13))
    xs = torch.linspace(-1, 1, 201, dtype=torch.float64)
    ground = torch.stack(torch.meshgrid(xs, xs, indexing="xy"), -1)  # [201, 201, 2]
    cloud = torch.randn(200, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    cloud = 0.05 * cloud
    peaks = []
    for height in (0.05, 0.2, 0.5):
        points = cloud + torch.tensor([0.1, 0.0, height], dtype=torch.float64)
        cover = shadow_cover(points, ground, light, spacing=0.02)
        assert float(cover.min()) >= 0 and float(cover.max()) < 1
        weights = cover / cover.sum()
        centre = (weights[..., None] * ground).sum((0, 1))
        expected = points[:, :2].mean(0) - points[:, 2].mean() * torch.tensor(light[:2]) / light[2]
        assert torch.allclose(centre, expected, atol=0.01)  # along the light, onto z = 0
        far = (ground - expected).norm(dim=-1) > 0.6
        assert float(cover[far].max()) < 1e-3
        peaks.append(float(cover.max()))
    assert peaks[0] > peaks[1] > peaks[2]


def test_shading_is_lambert_with_radial_normals():
    means = torch.tensor([[[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]]])
    colors = torch.full((1, 4, 3), 0.8)
    g = Gaussians.from_activated(means, torch.full((1, 4, 3), 0.1), torch.full((1, 4), 0.9), colors)
    light = (math.sin(0.5), 0.0, math.cos(0.5))
    shaded = shade_gaussians(g, look(light_direction=light, ambient=0.4)).colors[0, :, 0]
    direct = torch.tensor([math.cos(0.5), 0.0, math.sin(0.5), 0.0])  # n·l clamped at 0
    assert torch.allclose(shaded, 0.8 * (0.4 + 0.6 * direct), atol=1e-5)


def test_composite_keeps_the_object_and_darkens_only_the_shadowed_ground():
    cameras = dataset_views(24, 24, elevation_deg=35.0, target=(0.0, 0.0, 0.0))
    scene = look(light_direction=(0.0, 0.0, 1.0), ambient=0.4)
    background = scene_background(cameras, scene)
    rgb = torch.zeros(4, 1, 24, 24, 3, dtype=torch.float64)
    alpha = torch.zeros(4, 1, 24, 24, dtype=torch.float64)
    rgb[:, :, 0, 0] = 0.5
    alpha[:, :, 0, 0] = 1.0  # an opaque object pixel
    occluders = torch.tensor([[[0.0, 0.0, 0.05], [0.02, 0.0, 0.05]]])
    frames = composite_in_scene(rgb, alpha, occluders, background, scene, spacing=0.1)
    assert torch.allclose(frames[:, 0, 0, 0], torch.full((4, 3), 0.5, dtype=torch.float64))
    darker = background.backdrop.double() - frames[:, 0]
    darker[:, 0, 0] = 0  # the object's pixel
    assert float(darker.min()) >= -1e-6
    centre = darker[:, 10:14, 10:14].mean()  # the target (under the light) is in the middle
    assert float(centre) > 0.02 and float(darker[:, :3].abs().max()) < 1e-6  # sky untouched


def test_sensor_noise_has_the_asked_spread_and_is_seeded():
    frames = torch.full((2, 64, 64, 3), 0.5, dtype=torch.float64)
    noisy = add_sensor_noise(frames, 0.02, seed=3)
    assert abs(float((noisy - frames).std()) - 0.02) < 0.001
    assert torch.equal(noisy, add_sensor_noise(frames, 0.02, seed=3))
    assert torch.equal(add_sensor_noise(frames, 0.0, seed=3), frames)


def test_compression_decodes_close_to_the_input_and_lower_quality_is_smaller():
    y, x = np.mgrid[0:48, 0:48]
    frames = np.stack(
        [np.stack([(x + 2 * t) % 48 * 5, y * 5, np.full_like(x, 120)], -1) for t in range(6)]
    ).astype(np.uint8)
    sizes = {}
    for quality in (8.0, 3.0):
        decoded, data = compress_video(frames, fps=30.0, quality=quality)
        assert decoded.shape == frames.shape and decoded.dtype == np.uint8
        mse = float(np.mean((decoded.astype(float) - frames) ** 2))
        psnr = 10 * math.log10(255**2 / max(mse, 1e-9))
        assert psnr > (35 if quality == 8 else 22)
        sizes[quality] = len(data)
    assert sizes[3.0] < sizes[8.0]


def _chroma(rgb: torch.Tensor) -> torch.Tensor:  # [..., 3] → [...] max − min channel
    return rgb.max(-1).values - rgb.min(-1).values


def test_a_vivid_look_is_saturated_where_the_muted_one_never_is():
    """The vivid look (data's vivid_share) draws floors far more colourful than the muted look
    ever does (a tint of at most ±0.12 on a grey, the second colour a darker copy: a chroma
    below 0.4), and keeps the light and the noise."""
    rng = np.random.default_rng(1)
    muted = [draw_look(rng, (0.0, 0.02)) for _ in range(200)]
    vivid = [vivid_look(rng, m, 0.3) for m in muted]
    floor = torch.tensor([c for m in muted for c in m.ground_colors])
    assert float(_chroma(floor).max()) < 0.4
    vivid_floor = [_chroma(torch.tensor(v.ground_colors)).max() for v in vivid]
    assert np.mean([float(c) > 0.4 for c in vivid_floor]) > 0.6
    assert {v.ground_pattern for v in vivid} == set(VIVID_GROUND_PATTERNS)
    assert {v.object_pattern for v in vivid} == set(OBJECT_PATTERNS)
    assert all(v.light_direction == m.light_direction for v, m in zip(vivid, muted, strict=True))
    assert all(v.noise_sigma == m.noise_sigma for v, m in zip(vivid, muted, strict=True))


def test_a_contrast_floor_is_dark_and_bright_where_the_muted_one_never_is():
    """The high-contrast look (data's contrast_share) gives the floor a dark and a bright colour:
    their brightest channels ×2.4 apart or more, where the muted look's second colour is a copy
    of the first darkened ×0.5–0.85 (×2 at most); only the floor changes."""
    rng = np.random.default_rng(2)
    muted = [draw_look(rng, (0.0, 0.02)) for _ in range(200)]
    contrast = [contrast_look(rng, m) for m in muted]

    def ratio(colours) -> float:  # brightest channel of the brighter over the darker's
        values = sorted(max(c) for c in colours)
        return values[-1] / max(values[0], 1e-6)

    assert max(ratio(m.ground_colors) for m in muted) <= 2.0 + 1e-6
    assert min(ratio(c.ground_colors) for c in contrast) >= 2.4
    assert {c.ground_pattern for c in contrast} == set(CONTRAST_GROUND_PATTERNS)
    for c, m in zip(contrast, muted, strict=True):
        assert replace(c, ground_pattern=m.ground_pattern, ground_colors=m.ground_colors) == m


@pytest.mark.parametrize("pattern", OBJECT_PATTERNS[1:])
def test_a_printed_pattern_is_fixed_to_the_object(pattern):
    """The print is a function of the object's own frame-0 points: moving the object leaves
    every Gaussian's colour as it was, its colours come from the look's palette (mixed by
    object_mix), and "none" leaves the colours alone."""
    printed = look(
        object_pattern=pattern,
        object_colors=((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
        object_period=0.05,
        object_mix=1.0,
    )
    points = torch.rand(500, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    colours = torch.full((500, 3), 0.5, dtype=torch.float64)
    a = print_pattern(colours, points, printed, torch.Generator().manual_seed(3))
    b = print_pattern(colours, points + 2.0, printed, torch.Generator().manual_seed(3))
    assert torch.equal(a, b)
    palette = torch.tensor(printed.object_colors, dtype=torch.float64)
    assert bool(((a[:, None, :] - palette[None]).abs().sum(-1).min(1).values < 1e-9).all())
    assert len({tuple(c) for c in a.tolist()}) == 2  # both colours are used
    none = print_pattern(colours, points, look(), torch.Generator().manual_seed(3))
    assert torch.equal(none, colours)
