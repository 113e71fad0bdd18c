"""Gradient-free refinement (pipeline/search.py) and the ``reconphys_search`` evaluate method.

The search runs the simulator and renderer that made the dataset, so from wrong attributes it
must walk back to the true observables (checked against the sample's stored truth). One thread,
16-px frames, 24 anchors.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import pytest
import torch
from helpers import make_tiny_dataset

from reconphys.capture.window import object_window
from reconphys.physics import scene_stable_substeps, stable_substeps
from reconphys.physics.model import ATTRIBUTE_RANGES
from reconphys.pipeline.samples import load_sample
from reconphys.pipeline.search import (
    FINE_TEMPERATURE,
    MAX_SUPERSAMPLE,
    PREDICTED_GEOMETRY_TEMPERATURE,
    REBUILT_FINE_TEMPERATURE,
    REBUILT_TEMPERATURE_PIXELS,
    REFERENCE_PIXELS,
    TEMPERATURE_EXPONENT,
    TEMPERATURE_PIXELS,
    attributes_of,
    lighting_gain,
    network_intervals,
    observable_bounds,
    observables,
    profile_interval,
    profile_quantiles,
    render_compared,
    scaled_colours,
    search,
    substep_groups,
    supersampling,
    temperature_for,
)
from reconphys.threads import set_cpu_threads


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    threads = torch.get_num_threads()
    set_cpu_threads(1)
    yield
    set_cpu_threads(threads)


@pytest.fixture(scope="module")
def sample(tmp_path_factory):
    root = tmp_path_factory.mktemp("search") / "data"
    make_tiny_dataset(
        root,
        resolution=24,
        num_gaussians=200,
        num_anchors=24,
        num_neighbors=6,
        min_substeps=20,
        toss_fraction=1.0,  # a slide: friction shows
        seed=2,
    )  # fmt: skip  (a slide)
    manifest = json.loads((root / "manifest.json").read_text())
    return load_sample(root, manifest["samples"][0]["id"])


def test_search_walks_back_to_the_true_observables(sample):
    observation, truth = sample
    physics = truth.asset.physics
    true = observables(physics)
    wrong = replace(
        physics,
        stiffness=min(physics.stiffness * math.e**1.5, 1200.0),
        damping=max(physics.damping / math.e, 0.1),
        friction=0.9 if physics.friction < 0.5 else 0.1,
    )
    start = observables(wrong)
    found, history = search(replace(truth.asset, physics=wrong), observation.frames[:20],
                            observation.camera)  # fmt: skip
    after = observables(found.physics)
    before_error, after_error = (start - true).abs(), (after - true).abs()
    assert history["error"] <= min(history["rounds"][0]["errors"])  # never worse than a step
    ranges = ATTRIBUTE_RANGES
    for name in ("mass", "stiffness", "damping", "friction"):
        low, high = ranges[name]
        assert low <= getattr(found.physics, name) <= high
    bounds = observable_bounds()
    for i, (low, high) in enumerate(history["intervals"].values()):
        assert bounds[i, 0] <= low <= high <= bounds[i, 1]
    pixels = history["render_size"][0] * history["render_size"][1]
    assert history["temperature"] == pytest.approx(
        list(temperature_for(pixels, history["supersample"]))
    )
    assert after_error[0] < 0.25 * before_error[0], (true, start, after)  # log k/m
    assert after_error[2] < 0.5 * before_error[2], (true, start, after)  # friction
    assert after_error.sum() < 0.5 * before_error.sum()


def test_a_wider_temperature_widens_every_interval(sample):
    """temperature_scale (predict's 4× on the object-centric predictor's geometry) multiplies
    the profile posterior's temperature: every 10–90 % interval is at least as wide, and the
    sharpest one (log k/m of a slide seen whole) strictly wider."""
    observation, truth = sample
    widths = []
    for scale in (1.0, PREDICTED_GEOMETRY_TEMPERATURE):
        _, history = search(truth.asset, observation.frames[:20], observation.camera,
                            temperature_scale=scale)  # fmt: skip
        widths.append([high - low for low, high in history["intervals"].values()])
    assert all(wide >= narrow - 1e-9 for narrow, wide in zip(*widths, strict=True)), widths
    assert widths[1][0] > 1.2 * widths[0][0], widths


def test_search_refuses_a_single_frame(sample):
    observation, truth = sample
    with pytest.raises(ValueError, match="frames"):
        search(truth.asset, observation.frames[:1], observation.camera)


def test_search_keeps_what_the_video_does_not_show(sample, monkeypatch):
    """Where no candidate explains the frames better than another (an observable the video does
    not show), the start comes back unchanged, not a grid end."""
    from reconphys.pipeline import search as module

    observation, truth = sample
    monkeypatch.setattr(
        module, "photometric_errors", lambda a, f, c, x, **_: torch.full((len(x),), 1e-3)
    )
    found, history = search(truth.asset, observation.frames[:20], observation.camera)
    assert found.physics == truth.asset.physics
    assert len(history["rounds"]) == 9 + 3  # the spans, then one profile per observable
    bounds = observable_bounds()
    for i, (low, high) in enumerate(history["intervals"].values()):  # flat: the prior's 10–90 %
        width = float(bounds[i, 1] - bounds[i, 0])
        assert low == pytest.approx(float(bounds[i, 0]) + 0.1 * width, abs=0.01 * width)
        assert high == pytest.approx(float(bounds[i, 0]) + 0.9 * width, abs=0.01 * width)
    # with the network's belief: its normal around the start comes back, the start as its median
    sigma = torch.tensor([0.4, 0.5, 0.05], dtype=torch.float64)
    start = observables(truth.asset.physics)
    found, history = search(truth.asset, observation.frames[:20], observation.camera,
                            prior_sigma=sigma)  # fmt: skip
    assert history["undetermined"] == ["log_k_over_m", "log_d_over_m", "friction"]
    assert history["network_sigma"] == pytest.approx(sigma.tolist())
    assert observables(found.physics) == pytest.approx(start, abs=0.01 * float(sigma.min()) + 2e-2)
    expected = network_intervals(start, sigma)
    for name, (low, high) in history["intervals"].items():
        assert [low, high] == pytest.approx(expected[name], abs=0.02)


def test_profile_interval_of_a_sharp_minimum_is_narrow_and_holds_it():
    """Quadratic errors: the posterior is Gaussian with σ² = τ·E_min / (2a); its 10–90 % interval
    is ±1.2816 σ around the minimum."""
    values = torch.linspace(0.0, 10.0, 401, dtype=torch.float64)
    best, curvature, floor, temperature = 6.3, 0.01, 1e-2, 0.05
    errors = floor + curvature * (values - best) ** 2
    low, high = profile_interval(values, errors, (0.0, 10.0), temperature, points=4001)
    sigma = math.sqrt(temperature * floor / (2 * curvature))
    assert sigma > 0.1  # well resolved by the grid (0.025) and the quantile line (0.0025)
    assert low == pytest.approx(best - 1.2816 * sigma, abs=0.01)
    assert high == pytest.approx(best + 1.2816 * sigma, abs=0.01)


def test_a_normal_prior_times_a_profile_is_their_analytic_product():
    """A flat profile leaves the network's normal belief: median μ, 10–90 % μ ± 1.2816 σ. A
    quadratic profile (a normal likelihood, σ_L² = τ·E_min / (2a)) times the normal prior is the
    normal with precision 1/σ_L² + 1/σ² and the precision-weighted mean."""
    values = torch.linspace(0.0, 10.0, 401, dtype=torch.float64)
    mu, sigma = 4.0, 0.6
    flat = profile_quantiles(values, torch.full_like(values, 0.3), (0.0, 10.0), 0.05,
                             (0.1, 0.5, 0.9), prior=(mu, sigma), points=4001)  # fmt: skip
    assert flat == pytest.approx([mu - 1.2816 * sigma, mu, mu + 1.2816 * sigma], abs=0.01)
    best, curvature, floor, temperature = 6.3, 0.01, 1e-2, 0.05
    errors = floor + curvature * (values - best) ** 2
    sigma_l2 = temperature * floor / (2 * curvature)
    precision = 1 / sigma_l2 + 1 / sigma**2
    mean, spread = (best / sigma_l2 + mu / sigma**2) / precision, precision**-0.5
    both = profile_quantiles(values, errors, (0.0, 10.0), temperature, (0.1, 0.5, 0.9),
                             prior=(mu, sigma), points=4001)  # fmt: skip
    assert both == pytest.approx([mean - 1.2816 * spread, mean, mean + 1.2816 * spread], abs=0.01)
    assert mu < both[1] < best  # between the two, nearer the sharper (the profile)
    # without a prior: the flat-prior interval of profile_interval
    assert profile_quantiles(values, errors, (0.0, 10.0), temperature, points=4001) == list(
        profile_interval(values, errors, (0.0, 10.0), temperature, points=4001)
    )


def test_the_networks_own_intervals_are_its_normal_belief_cut_to_the_reachable_range():
    bounds = observable_bounds()
    centre = torch.tensor([4.0, float(bounds[1, 1]) - 0.1, 0.5], dtype=torch.float64)
    sigma = torch.tensor([0.5, 1.0, 0.1], dtype=torch.float64)
    out = network_intervals(centre, sigma)
    assert list(out) == ["log_k_over_m", "log_d_over_m", "friction"]
    assert out["log_k_over_m"] == pytest.approx([4.0 - 0.6408, 4.0 + 0.6408], abs=1e-4)
    assert out["log_d_over_m"][1] == pytest.approx(float(bounds[1, 1]))  # cut at the bound
    assert out["friction"] == pytest.approx([0.5 - 0.12816, 0.5 + 0.12816], abs=1e-4)


def test_the_temperature_falls_as_the_compared_pixels_grow():
    """τ = products / REFERENCE_PIXELS × (REFERENCE_PIXELS / pixels)^TEMPERATURE_EXPONENT: at the
    reference, τ·pixels is the product; four times the pixels, 4^exponent less τ; and on a
    quadratic profile the interval's width goes as √τ."""
    assert temperature_for(REFERENCE_PIXELS) == pytest.approx(
        [t / REFERENCE_PIXELS for t in TEMPERATURE_PIXELS]
    )
    shrink = 4.0**TEMPERATURE_EXPONENT
    assert temperature_for(4000) == pytest.approx([t / shrink for t in temperature_for(1000)])
    values = torch.linspace(0.0, 10.0, 401, dtype=torch.float64)
    errors = 1e-2 + 0.01 * (values - 5.0) ** 2
    widths = [
        (lambda lo_hi: lo_hi[1] - lo_hi[0])(
            profile_interval(values, errors, (0.0, 10.0), temperature_for(p)[0], points=4001)
        )
        for p in (1000, 4000)
    ]
    assert widths[1] == pytest.approx(widths[0] / shrink**0.5, rel=0.02)


def test_a_rebuilt_asset_keeps_the_law_its_factors_were_chosen_under():
    """A predicted or given shape (rebuilt=True): τ = REBUILT_TEMPERATURE_PIXELS / pixels (× the
    rebuilt fine factors when supersampled), not the own asset's steeper law: the two agree at
    no size but are each what their calibration says."""
    for pixels in (300, 1024, 3300):
        assert temperature_for(pixels, rebuilt=True) == pytest.approx(
            [t / pixels for t in REBUILT_TEMPERATURE_PIXELS]
        )
        assert temperature_for(pixels, supersample=2, rebuilt=True) == pytest.approx(
            [
                t * f / pixels
                for t, f in zip(REBUILT_TEMPERATURE_PIXELS, REBUILT_FINE_TEMPERATURE, strict=True)
            ]
        )
    assert temperature_for(3300)[1] < 0.2 * temperature_for(3300, rebuilt=True)[1]


def test_a_supersampled_comparison_has_its_own_temperature():
    """Fine assets (compared supersampled) take TEMPERATURE_PIXELS × FINE_TEMPERATURE, whatever
    the factor s > 1; coarse ones TEMPERATURE_PIXELS alone."""
    coarse = temperature_for(REFERENCE_PIXELS)
    assert coarse == pytest.approx([t / REFERENCE_PIXELS for t in TEMPERATURE_PIXELS])
    for s in (2, 3, MAX_SUPERSAMPLE):
        fine = temperature_for(REFERENCE_PIXELS, supersample=s)
        assert fine == pytest.approx([c * f for c, f in zip(coarse, FINE_TEMPERATURE, strict=True)])


def test_attributes_of_keeps_the_mass_unless_a_ratio_needs_another():
    mass = 1.0
    values = torch.tensor([[math.log(300.0), math.log(2.0), 0.4],  # reachable with m = 1
                           [math.log(3000.0), math.log(2.0), 0.4],  # k/m = 3000: m ≤ 0.4
                           [math.log(5.0), math.log(0.05), 0.4]],  # d/m = 0.05: m ≥ 2
                          dtype=torch.float64)  # fmt: skip
    out = attributes_of(values, mass)
    assert out["mass"].tolist() == pytest.approx([1.0, 0.4, 2.0])
    ratios = torch.stack([out["stiffness"] / out["mass"], out["damping"] / out["mass"]], 1)
    assert ratios.log() == pytest.approx(values[:, :2], abs=1e-9)  # the ratios are exact


def test_substeps_per_candidate_and_their_groups(sample):
    _, truth = sample
    asset = truth.asset
    model = asset.model()
    stiff = [10.0, 30.0, 100.0, 1000.0]
    x0 = asset.x0[None].expand(len(stiff), -1, -1)
    batch = model.with_attributes(stiffness=torch.tensor(stiff), mass=torch.ones(len(stiff)))
    need = scene_stable_substeps(batch, x0, 0.03, 1)
    assert max(need) == stable_substeps(batch, x0, 0.03, 1)  # the batch's is the largest
    for b, k in enumerate(stiff):  # each alone as stable_substeps computes it
        one = model.with_attributes(stiffness=torch.tensor([k]), mass=torch.ones(1))
        assert need[b] == stable_substeps(one, x0[:1], 0.03, 1)
    assert need == sorted(need) and need[-1] > need[0]
    groups = substep_groups([10, 40, 11, 12, 41, 100], ratio=1.5)
    assert groups == [[0, 2, 3], [1, 4], [5]]


def test_a_cropped_camera_renders_the_crop_of_the_full_image(sample):
    """The search compares only the object's window: its camera (principal point moved) must
    render exactly that window of the full image."""
    from reconphys.render import render

    observation, truth = sample
    camera = observation.camera
    full = render(truth.asset.gaussians, camera.cameras()).rgb[0]  # [H, W, 3]
    left, top, width, height = 3, 5, 14, 11
    window = render(truth.asset.gaussians, camera.cropped(left, top, width, height).cameras())
    crop = full[top : top + height, left : left + width]
    assert window.rgb[0].shape == crop.shape
    assert torch.allclose(window.rgb[0], crop, atol=1e-5)


def test_fine_gaussians_are_compared_as_their_full_size_render_area_averaged(sample):
    """An asset of Gaussians far below the comparison's pixel (a dense PLY, the paper's 20,000):
    rendered straight at the comparison size it is not the area average of its full-size render
    (each Gaussian dilated to a pixel, the back showing through); supersampled, it is. Coarse
    Gaussians are rendered as before."""
    import torch.nn.functional as F

    from reconphys.render import render

    observation, truth = sample
    coarse = truth.asset.gaussians
    # many more, smaller Gaussians on the same object: copies jittered within the old ones
    g = torch.Generator().manual_seed(0)
    copies = 12
    means = coarse.means.repeat(copies, 1)
    means = means + torch.randn(means.shape, generator=g) * coarse.scales.repeat(copies, 1)
    fine = coarse.map(lambda t: t.repeat(copies, *([1] * (t.dim() - 1)))).with_means(means)
    fine = replace(fine, log_scales=fine.log_scales + math.log(0.1))
    big = observation.camera.resized(8 * 24, 8 * 24)
    camera = observation.camera.resized(24, 24)
    assert supersampling(coarse, camera, recorded_scale=8.0) == 1
    assert supersampling(fine, camera, recorded_scale=1.0) == 1  # no more pixels recorded
    scale = supersampling(fine, camera, recorded_scale=8.0)
    assert scale > 1
    full = render(fine.map(lambda t: t[None]), big.cameras()).rgb[0, 0]  # [192, 192, 3]
    averaged = F.avg_pool2d(full.permute(2, 0, 1)[None], 8)[0].permute(1, 2, 0)
    direct = render_compared(fine.map(lambda t: t[None]), camera)[0][0]
    supersampled = render_compared(fine.map(lambda t: t[None]), camera, scale)[0][0]
    direct_error = float(((direct - averaged) ** 2).mean())
    assert float(((supersampled - averaged) ** 2).mean()) < 0.25 * direct_error


def test_object_window_holds_every_frame_mask_with_a_margin():
    masks = torch.zeros(3, 40, 50)
    masks[0, 10:14, 20:24] = 1  # falls and slides right
    masks[2, 30:34, 28:36] = 1
    left, top, width, height = object_window(masks, margin=0.25)
    # box rows 10..33 (24 tall: grow 6), cols 20..35 (16 wide: grow 4)
    assert (left, top, width, height) == (16, 4, 24, 36)
    assert object_window(torch.zeros(2, 8, 8)) is None
    edge = torch.zeros(1, 10, 10)
    edge[0, 0:3, 7:10] = 1
    assert object_window(edge) == (5, 0, 5, 5)  # clipped to the image


def test_a_clip_that_ends_before_the_contact_shows_no_observable(sample):
    """Before the object touches the ground it falls as a rigid body: no frame tells its stiffness,
    damping or friction, and the intervals must say so (wide: most of the prior's 10–90 %), not
    give a confident value."""
    observation, truth = sample
    heights = truth.asset.simulate(19).x[0, :, :, 2].amin(-1)  # [T] lowest anchor per frame
    contact = int((heights <= truth.asset.physics.ground_height + 1e-3).nonzero()[0])
    assert contact >= 3, contact
    frames = observation.frames[:contact]  # frames before the first contact
    wrong = replace(
        truth.asset.physics, friction=0.9, stiffness=min(1200.0, 3 * truth.asset.physics.stiffness)
    )
    found, history = search(replace(truth.asset, physics=wrong), frames, observation.camera,
                            spans=(0.25,))  # fmt: skip
    assert history["undetermined"] == ["log_k_over_m", "log_d_over_m", "friction"]
    assert found.physics == wrong  # nothing shown, nothing moved: the start is kept
    bounds = observable_bounds()
    for i, (name, (low, high)) in enumerate(history["intervals"].items()):
        prior = 0.8 * float(bounds[i, 1] - bounds[i, 0])
        assert high - low > 0.7 * prior, (name, low, high)


def test_the_scene_light_is_measured_and_divided_out_of_the_comparison(sample):
    """A recording whose object shows darker (the realistic look's light and shading) is read by
    its per-channel gain; the plain renders' gain is 1; and the search on the darkened frames
    keeps its error floor at the plain one's instead of the colour difference."""
    observation, truth = sample
    camera = observation.camera
    plain = lighting_gain(truth.asset.gaussians, observation.frames[0], camera)
    assert torch.allclose(plain, torch.ones(3), atol=0.03)
    light = torch.tensor([0.5, 0.7, 0.9])
    darker = observation.frames * light
    assert torch.allclose(lighting_gain(truth.asset.gaussians, darker[0], camera), light, atol=0.03)
    scaled = scaled_colours(truth.asset.gaussians, light)
    assert torch.allclose(scaled.colors, (truth.asset.gaussians.colors * light).clamp(0, 1))
    frames = observation.frames[:12]
    _, bright = search(truth.asset, frames, camera, spans=(0.25,), profiles=False)
    _, dark = search(truth.asset, frames * light, camera, spans=(0.25,), profiles=False)
    assert dark["lighting_gain"] == pytest.approx(light.tolist(), abs=0.03)
    assert dark["error"] < 2 * bright["error"] + 1e-4


def _true_motion(sample) -> torch.Tensor:  # [6] the sample's initial (linear, angular) velocity
    from reconphys.data import DropDataset

    _, truth = sample
    dataset = DropDataset(truth.root, views=[0], verify=False)
    state = dataset.meta(dataset.index_of(truth.id))["initial_state"]
    return torch.tensor(state["linear_velocity"] + state["angular_velocity"], dtype=torch.float64)


def test_the_true_initial_motion_is_a_fixed_point_of_the_motion_search(sample):
    """From the true attributes and the true initial motion, every candidate is at best as good:
    the search keeps them, and the motion comes back through the camera's axes unchanged."""
    observation, truth = sample
    motion = _true_motion(sample)
    found, history = search(
        truth.asset, observation.frames[:20], observation.camera,
        masks=observation.masks[:20], motion=motion, profiles=False,
    )  # fmt: skip
    found_motion = torch.tensor(history["initial_motion"], dtype=torch.float64)
    assert torch.allclose(found_motion, motion, atol=1e-6)
    assert torch.allclose(found.v0, truth.asset.v0, atol=1e-5)
    # (log d/m within the clamp of a damping at its range's end when the mass is re-held)
    assert observables(found.physics).allclose(observables(truth.asset.physics), atol=0.1)


def test_the_motion_search_finds_the_spin_and_the_speed_along_the_view(sample):
    """Started as predict starts it (no spin; the velocity along the view 0.4 m/s off, which the
    masks barely show), the search with the true attributes moves the initial motion most of the
    way back to the truth, and the asset's v0 is the rigid motion it reports."""
    from reconphys.geometry import rigid_velocity

    observation, truth = sample
    motion = _true_motion(sample)
    towards_camera = -observation.camera.world_to_cam[2, :3].double()  # world, unit
    start = motion.clone()
    start[:3] += 0.4 * towards_camera
    start[3:] = 0.0
    found, history = search(
        truth.asset, observation.frames[:20], observation.camera,
        masks=observation.masks[:20], motion=start, profiles=False,
    )  # fmt: skip
    result = torch.tensor(history["initial_motion"], dtype=torch.float64)
    before, after = (start - motion).norm(), (result - motion).norm()
    assert after < 0.5 * before, (motion, start, result)
    assert (result[:3] - motion[:3]).norm() < 0.2, (motion, result)
    expected = rigid_velocity(truth.asset.x0.double(), result[:3], result[3:])
    assert torch.allclose(found.v0.double(), expected, atol=1e-5)


def test_a_lowered_ground_is_the_object_raised_over_it_and_drawn_back(sample):
    """photometric_errors' ``lowered``: the object simulated Δ higher over the asset's ground and
    drawn Δ lower scores as the asset whose ground is Δ lower (the physics is the same under a
    vertical shift: an independent route through the simulator); Δ = 0 is the asset itself."""
    from reconphys.pipeline.search import photometric_errors

    observation, truth = sample
    frames, camera = observation.frames[:20], observation.camera
    candidates = observables(truth.asset.physics)[None].repeat(3, 1)
    lowered = torch.tensor([0.0, 0.03, -0.02], dtype=torch.float64)
    shifted = photometric_errors(truth.asset, frames, camera, candidates, lowered=lowered)
    for delta, error in zip(lowered.tolist(), shifted, strict=True):
        physics = replace(
            truth.asset.physics, ground_height=truth.asset.physics.ground_height - delta
        )
        moved = replace(truth.asset, physics=physics)
        alone = photometric_errors(moved, frames, camera, candidates[:1])
        assert float(error) == pytest.approx(float(alone[0]), rel=1e-4, abs=1e-7)
    assert float(shifted[1]) != pytest.approx(float(shifted[0]), rel=1e-3)  # it does move


def test_the_ground_search_finds_a_ground_read_four_centimetres_high(sample):
    """A camera read from the video puts the ground a few cm off: the asset's ground 4 cm too
    high (it lands early) is lowered back by the search to within its finest step; from the
    true ground it stays within that step."""
    from reconphys.pipeline.search import GROUND_SPAN_SCALE, SPANS

    observation, truth = sample
    frames, camera = observation.frames[:20], observation.camera
    true_ground = truth.asset.physics.ground_height
    step = SPANS[-1] * GROUND_SPAN_SCALE
    for offset in (0.04, 0.0):
        physics = replace(truth.asset.physics, ground_height=true_ground + offset)
        found, history = search(
            replace(truth.asset, physics=physics), frames, camera, profiles=False, ground=True
        )
        assert history["ground_lowered_m"] == pytest.approx(offset, abs=step)
        assert found.physics.ground_height == pytest.approx(true_ground, abs=step)
    _, history = search(truth.asset, frames, camera, profiles=False)
    assert history["ground_lowered_m"] is None
