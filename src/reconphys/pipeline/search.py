"""Gradient-free refinement: fit the observables to a recording by batched re-simulation, and say
how well the recording pins each of them down.

Only k/m, d/m and the friction are observable (docs/design.md#identifiability), so the search moves
those three; the mass only follows where a ratio could not be reached with the predicted mass
inside the attribute ranges (:func:`attributes_of`). Two stages, each a few batched rollouts:

1. **Coordinate search**: for each span (coarse to fine) and each observable, ``candidates`` values
   around the current one (the other two fixed) are simulated as one batch from the asset's
   initial state, rendered into the recording's camera and compared with frames 1..T−1 by mean
   squared error; the best is kept.
2. **Profiles**: for each observable, a grid over its whole range plus a fine grid around the best
   (the other two at their best) — a wrong network start far from the truth is caught here, and
   the profile gives the interval: a posterior ∝ exp(−(E − E_min) / (τ·E_min)) over the profile,
   i.e. Gaussian pixel noise whose variance is the best fit's residual, with τ = 2 / (effective
   number of independent pixels), inversely proportional to the pixels compared, one constant per
   observable calibrated on validation meshes the model never trained on
   (:func:`temperature_for`). An
   observable the video does not show (the friction of an object that never slides) has a flat
   profile and comes out as a wide interval; when it is nearly the prior's (:data:`UNDETERMINED`),
   the start value is kept for it instead of a best fit that is noise.

With ``motion`` (the initial linear and angular velocity), six more coordinates join the
coordinate search (the velocity in the camera's axes, the spin in the world's); the profiles stay
those of the three observables. ``predict`` does not use it yet (docs/usage.md "Searching the
initial motion with the physics": it recovers the motion from a sample's own asset, not yet the
physics through predict's rebuilt one).

With ``ground`` the ground's height is one more coordinate (a camera read from the video puts it
a few cm off): each candidate simulated raised over the asset's ground and drawn back, the asset's
ground lowered by the best. ``predict(search_ground=True)`` uses it; measured and not the default
(docs/usage.md "Searching the ground with the physics").

Each round is one batched rollout and one batched render, so a whole search costs seconds at 64 px
and 256 anchors on two cores (docs/training.md "Refinement by batched search"), against minutes
for gradient steps, and it needs no gradient through contact, which is what moves friction.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import torch
import torch.nn.functional as F
from torch import Tensor

from ..assets.asset import Asset
from ..assets.gaussians import SH_C0, Gaussians
from ..capture import CameraSpec
from ..capture.calibrate import Z_10_90  # the normal's 90 % quantile (QUANTILES[1])
from ..capture.window import comparison_view, object_window
from ..geometry import rigid_velocity
from ..physics import SpringMassModel, State, deform_means, rollout, scene_stable_substeps
from ..physics.model import ATTRIBUTE_RANGES, observable_bounds
from ..render import render

SPANS = (2.0, 0.7, 0.25)  # half-widths of the candidate grids in natural log of k/m and d/m
FRICTION_SPAN_SCALE = 0.25  # friction's half-width = span × this
# The initial motion, when searched: the linear velocity in the camera's axes (right, down,
# along the view), the angular velocity in the world's.
MOTION_NAMES = ("v_right", "v_down", "v_view", "w_x", "w_y", "w_z")
ACROSS_VIEW_SPANS = (0.7, 0.25)  # the velocity across the view (the masks show it) only finely
MOTION_BOUNDS = torch.tensor([[-3.0, 3.0]] * 3 + [[-8.0, 8.0]] * 3, dtype=torch.float64)
V_SPAN_SCALE, W_SPAN_SCALE = 0.2, 0.75  # m/s and rad/s per unit of span
SPAN_SCALES = (1.0, 1.0, FRICTION_SPAN_SCALE) + (V_SPAN_SCALE,) * 3 + (W_SPAN_SCALE,) * 3
# The ground, when searched (a camera read from the video): lowered by up to GROUND_RANGE_M
# either way, GROUND_SPAN_SCALE metres per unit of span (±6, ±2.1, ±0.75 cm by SPANS)
GROUND_RANGE_M = 0.15
GROUND_SPAN_SCALE = 0.03
CANDIDATES = 7  # values per observable and round (one batched rollout)
# The comparison is smaller than the recording (its frames area-averaged down to ``resolution``).
# Rendering a fine asset (a dense PLY, the paper's 20,000 Gaussians) straight at that size is not
# what the average of its full-size render looks like: each Gaussian below a pixel is dilated to
# a pixel-sized blob at full opacity, the back of the object shows through, and every candidate's
# error is dominated by that, not by the motion (the profiles go flat). So where the Gaussians'
# median σ is below FINE_SIGMA_PX pixels of the comparison, it is rendered s× larger (s = 2–4, up
# to the recording's own size, at most MAX_SUPERSAMPLE×, in gsplat's antialiased mode) and
# area-averaged back down (docs/rendering.md "Rendering smaller than the Gaussians were made for").
FINE_SIGMA_PX = 0.75
MAX_SUPERSAMPLE = 4
MIN_SUBSTEPS = 25  # as the cpu_small training recipe and pipeline/refine.py
# A candidate replaces the current value only if its error is lower by this fraction: where the
# video does not show an observable (all errors alike), the start is kept, not a grid end.
TIE = 1e-6
OBSERVABLES = ("log_k_over_m", "log_d_over_m", "friction")
PROFILE_POINTS = 9  # evenly over each observable's range
PROFILE_LOCAL = (-1.0, -0.5, -0.2, 0.2, 0.5, 1.0)  # × the last span, around the best
# Temperature of the profile posterior on a sample's own asset and initial state (``evaluate``'s
# † search, ``predict --sample``), relative to the best error: τ = 2 / (effective number of
# independent pixels), and that number grows with the pixels compared (the window after
# :func:`comparison_view`, at most 64 px a side). Measured, it grows faster than the pixels: on
# validation meshes the shipped model never trained on, the τ whose 10–90 % intervals cover the
# truth 80 % of the time is ~4× smaller at 128-px recordings (~3,300 pixels compared) than a
# τ ∝ 1/pixels law carried from 32 px (~770) gives, so τ = TEMPERATURE_PIXELS / REFERENCE_PIXELS ×
# (REFERENCE_PIXELS / pixels)^TEMPERATURE_EXPONENT, one product per observable (at 1,024 pixels, a
# 32 × 32 comparison, τ·pixels = TEMPERATURE_PIXELS). Calibrated by ``benchmarks/
# search_refinement.py --rows`` on data/val200 (100 drops and tosses at 32 px) and data/val128 (80
# drops at 128 px), never a test split: exponent 2 puts both sizes' 80 % points at one product per
# observable (81 % / 83 % log k/m, 78 % / 81 % log d/m, 80 % / 78 % friction, 32 / 128 px); the
# 1/pixels law (exponent 1, products 1000 / 1500 / 500, chosen at 32 px on an earlier model) covered
# 73 / 88 / 79 % at 32 px and 92 / 92 / 84 % at 128 px. docs/training.md "Intervals".
REFERENCE_PIXELS = 1024
TEMPERATURE_EXPONENT = 2.0
TEMPERATURE_PIXELS = (1000.0, 500.0, 400.0)  # log k/m, log d/m, friction: τ·pixels at 1,024 pixels
# The law on a rebuilt asset (a predicted shape, a given PLY or mesh: ``search(rebuilt=True)``,
# what ``predict`` searches, its profiles times the network's belief): the law before, τ =
# (1000, 1500, 500) / pixels (× (2.5, 1, 3) supersampled), under which the two factors below and
# the belief factors were chosen. There the fit's error is the wrong shape, spring layout and
# initial state more than pixel noise, and does not shrink with the pixels: the law above made
# the answers worse on 40 plain validation drops at 128 px read without a PLY (MAE log k/m / log
# d/m 0.242 / 0.511 → 0.294 / 0.633; docs/training.md "Intervals").
REBUILT_TEMPERATURE_PIXELS = (1000.0, 1500.0, 500.0)
REBUILT_TEMPERATURE_EXPONENT = 1.0
REBUILT_FINE_TEMPERATURE = (2.5, 1.0, 3.0)
# × the temperature on the object-centric 3DGS predictor's geometry (no PLY given): the model is
# wrong in more than pixel noise there — the predicted shape's hidden side, size and spring layout
# differ from the object's, and the best fit of k/m compensates for them. Chosen on 20 realistic
# validation drops (the test splits of data/real_pybullet and data/real_pybullet2: meshes held
# out of every network's training, never the test sets): at 1× the search moved log k/m on 7 of
# the 20, each time further from the truth (MAE 1.54 / 1.95 with a camera file: 0.52× / 0.63× the
# midpoint guess's), at 4× the errors are 0.52 / 1.01 (1.54× / 1.21×), the same as at 16× on the
# first folder; docs/usage.md "Realistic recordings end to end".
PREDICTED_GEOMETRY_TEMPERATURE = 4.0  # × the rebuilt asset's law
# × the temperature on a given PLY or mesh (``predict --gaussians/--mesh``), whose fit is also
# multiplied by the network's belief: the shape is the object's, but the initial state is read
# from the masks (the velocity along the view is poorly seen, the spin not at all) and the frames
# are decoded from the recording, so the best fit of k/m compensates for a wrong start. Chosen
# through ``predict`` on 30 plain drops of validation meshes at 128 px (data/val128, meshes no
# network trained on; never a test split), the true Gaussians and camera file given: MAE of
# log k/m / log d/m / f 0.446 / 0.616 / 0.188 with the profiles alone at 1× (the network alone:
# 0.266 / 0.548 / 0.166), 0.260 / 0.528 / 0.178 times the belief at 1×, 0.254 / 0.537 / 0.165
# at 4× (intervals cover 80 % / 67 % / 77 %). On 32-px recordings the MAE does not move and the
# intervals come out too narrow (about 60 %); docs/usage.md "A given shape".
GIVEN_GEOMETRY_TEMPERATURE = 4.0  # × the rebuilt asset's law
# × the temperature (log k/m, log d/m, f) where the comparison is supersampled (a fine asset: a
# dense PLY, the paper's 20,000 Gaussians at 512 px; a third of the data's 2,000-Gaussian assets at
# 128 px). The best fit's residual is then far smaller than a coarse asset's, but the fit's error
# does not shrink as much, so the profiles need a larger τ. Calibrated by ``benchmarks/
# search_refinement.py --rows`` on validation meshes only, pooled: the 22 supersampled drops of
# data/val128 (2×, 128 px) and data/val512 (30 paper-preset drops at 512 px, 2–4×, searched from
# the model shipped before 2026-11-27's three-draw ensemble): the products nearest 80 % are 5000 /
# 4000 / 2500 (covering 86 / 91 / 86 % at 128 px, 73 / 83 / 77 % at 512 px). Not applied on the
# 3DGS predictor's geometry (``search(fine_temperature=False)``), whose
# PREDICTED_GEOMETRY_TEMPERATURE was chosen and checked as that geometry is compared;
# docs/training.md "Intervals".
FINE_TEMPERATURE = (5.0, 8.0, 6.25)
QUANTILES = (0.1, 0.9)
# An observable whose interval is at least this share of the prior's own 10–90 % width is not
# shown by the recording: its best fit is noise (or a wrong geometry compensating), so the start
# (the network's value) is kept for it and the history lists it under "undetermined".
UNDETERMINED = 0.75


def observables(physics) -> Tensor:  # [3] (log k/m, log d/m, f)
    return torch.tensor(
        [
            math.log(physics.stiffness / physics.mass),
            math.log(physics.damping / physics.mass),
            physics.friction,
        ],
        dtype=torch.float64,
    )


def attributes_of(values: Tensor, mass: float) -> dict[str, Tensor]:
    """(log k/m, log d/m, f) [B, 3] → mass, stiffness, damping, friction [B] inside the attribute
    ranges. The mass is kept unless a ratio needs another one (k/m = 3000 with a 1-kg prediction):
    then the nearest mass that holds both ratios inside the ranges (any mass gives the same
    motion, docs/design.md#identifiability); where none does, k and d are clamped."""
    r = ATTRIBUTE_RANGES
    k_over_m, d_over_m = values[:, 0].exp(), values[:, 1].exp()
    lowest = torch.stack(
        [torch.full_like(k_over_m, r["mass"][0]), r["stiffness"][0] / k_over_m,
         r["damping"][0] / d_over_m]
    ).amax(0)  # fmt: skip
    highest = torch.stack(
        [torch.full_like(k_over_m, r["mass"][1]), r["stiffness"][1] / k_over_m,
         r["damping"][1] / d_over_m]
    ).amin(0)  # fmt: skip
    fits = lowest <= highest
    held = torch.where(fits, torch.maximum(torch.minimum(torch.full_like(lowest, mass), highest),
                                           lowest), torch.full_like(lowest, mass))  # fmt: skip
    return {
        "mass": held,
        "stiffness": (k_over_m * held).clamp(*r["stiffness"]),
        "damping": (d_over_m * held).clamp(*r["damping"]),
        "friction": values[:, 2].clamp(*r["friction"]),
    }


def _candidate_model(asset: Asset, values: dict[str, Tensor]) -> SpringMassModel:
    physics = asset.physics
    return SpringMassModel(
        asset.springs,
        asset.rest_length,
        values["mass"].float(),
        values["stiffness"].float(),
        values["damping"].float(),
        values["friction"].float(),
        spring_exponent=physics.spring_exponent,
        restitution=physics.restitution,
        gravity=tuple(physics.gravity),
        ground_height=physics.ground_height,
    )


SUBSTEP_GROUP_RATIO = 1.5  # candidates whose stable substeps differ less than this share a rollout


def substep_groups(need: list[int], ratio: float = SUBSTEP_GROUP_RATIO) -> list[list[int]]:
    """Candidate indices grouped by the substeps they need (sorted; within a group the largest is
    < ``ratio`` × the smallest): a stiff candidate does not make the whole batch take its steps."""
    order = sorted(range(len(need)), key=need.__getitem__)
    groups = [[order[0]]]
    for b in order[1:]:
        if need[b] < ratio * need[groups[-1][0]]:
            groups[-1].append(b)
        else:
            groups.append([b])
    return groups


@torch.no_grad()
def supersampling(
    gaussians: Gaussians,  # the object at frame 0
    camera: CameraSpec,  # the comparison's camera
    recorded_scale: float,  # the recording's pixels per comparison pixel (≥ 1)
) -> int:
    """How many times larger than the comparison to render (:data:`FINE_SIGMA_PX`): enough for the
    median Gaussian's σ to reach FINE_SIGMA_PX pixels, never beyond the recording's own size nor
    MAX_SUPERSAMPLE; 1 for every asset whose Gaussians are not below that size."""
    rotation, translation = camera.world_to_cam[:3, :3], camera.world_to_cam[:3, 3]
    depth = (gaussians.means.double() @ rotation.double().T + translation.double())[:, 2]
    sigma = gaussians.scales.double().prod(-1) ** (1.0 / 3.0)  # geometric mean, metres
    in_front = depth > 1e-3
    if not bool(in_front.any()):
        return 1
    pixels = float((sigma[in_front] * float(camera.K[0, 0]) / depth[in_front]).median())
    if pixels >= FINE_SIGMA_PX:
        return 1
    need = math.ceil(FINE_SIGMA_PX / max(pixels, 1e-6))
    return max(1, min(need, MAX_SUPERSAMPLE, math.ceil(recorded_scale - 1e-6)))


def render_compared(
    gaussians: Gaussians,  # tensors [B, N, ·]
    camera: CameraSpec,  # the comparison's camera (h × w)
    supersample: int = 1,
) -> tuple[Tensor, Tensor]:  # rgb [B, h, w, 3], alpha [B, h, w]
    """Render into the comparison's camera; with ``supersample`` s > 1, at s·h × s·w in gsplat's
    antialiased mode, then each s × s block averaged (the full-size frame's area average)."""
    if supersample == 1:
        out = render(gaussians, camera.cameras())
        return out.rgb[:, 0], out.alpha[:, 0]
    s = supersample
    fine = camera.resized(camera.width * s, camera.height * s)
    out = render(gaussians, fine.cameras(), antialiased=True)
    rgb = F.avg_pool2d(out.rgb[:, 0].permute(0, 3, 1, 2), s).permute(0, 2, 3, 1)
    return rgb, F.avg_pool2d(out.alpha[:, 0, None], s)[:, 0]


@torch.no_grad()
def photometric_errors(
    asset: Asset,
    frames: Tensor,  # [T, H, W, 3] in [0, 1], frame 0 = the initial state
    camera: CameraSpec,  # the frames' camera, at their size
    candidates: Tensor,  # [B, 3] (log k/m, log d/m, f) or [B, 9] (+ initial motion, m/s, rad/s)
    min_substeps: int = MIN_SUBSTEPS,
    silhouettes: Tensor | None = None,  # [T, H, W] the object's masks at the frames' size
    silhouette_weight: float = 0.0,  # × the mean squared error of rendered alpha − mask
    supersample: int = 1,  # rendered this many times larger, then area-averaged (supersampling)
    lowered: Tensor | None = None,  # [B] metres: each candidate's ground this much lower
) -> Tensor:  # [B] mean squared error over frames 1..T−1
    """Simulate the asset with each candidate's observables and score its video. With 9 columns
    the last six are the initial linear (m/s) and angular (rad/s, about the anchors' centroid)
    velocity of a rigid motion, replacing the asset's v0. With ``lowered`` each candidate's
    ground lies that much lower: simulated as the object raised over the asset's ground, then
    drawn lowered back (the same world, the camera unmoved)."""
    count, physics = len(candidates), asset.physics
    values = attributes_of(candidates, physics.mass)
    steps = frames.shape[0] - 1
    x0 = asset.x0[None].expand(count, -1, -1)
    if lowered is not None:
        raise_by = torch.zeros(count, 1, 3, dtype=x0.dtype, device=x0.device)
        raise_by[:, 0, 2] = lowered.to(x0)
        x0 = x0 + raise_by
    need = scene_stable_substeps(
        _candidate_model(asset, values), x0, physics.frame_dt, min_substeps
    )
    need = need * count if len(need) == 1 else need
    x = x0.new_empty(count, steps + 1, *x0.shape[1:])
    for group in substep_groups(need):
        index = torch.tensor(group)
        model = _candidate_model(asset, {n: v[index] for n, v in values.items()})
        if candidates.shape[1] == 9:
            motion = candidates[index, 3:].to(x0)
            v0 = rigid_velocity(x0[index], motion[:, :3], motion[:, 3:])
        else:
            v0 = asset.v0[None].expand(len(group), -1, -1)
        state = State(x0[index], v0)
        substeps = max(need[b] for b in group)
        x[index] = rollout(model, state, steps, physics.frame_dt, substeps=substeps).x
    if lowered is not None:
        x = x - raise_by[:, None]
    x = x[:, 1:].reshape(count * steps, -1, 3)  # [B·(T−1), N_A, 3]
    g = asset.gaussians
    means = deform_means(g.means, asset.x0[None], x, asset.binding_index, asset.binding_weight)
    batch = g.map(lambda t: t.expand(len(x), *t.shape)).with_means(means)
    rgb, alpha = render_compared(batch, camera, supersample)
    images = rgb.reshape(count, steps, *frames.shape[1:])
    error = ((images - frames[1:][None]) ** 2).mean((1, 2, 3, 4))
    if silhouettes is not None and silhouette_weight > 0:
        alpha = alpha.reshape(count, steps, *frames.shape[1:3])
        error = error + silhouette_weight * ((alpha - silhouettes[1:][None]) ** 2).mean((1, 2, 3))
    return error


MIN_GAIN_PIXELS = 20  # object pixels needed to measure the lighting


def lighting_gain(
    gaussians: Gaussians,  # the object at frame 0
    frame: Tensor,  # [H, W, 3] the recording's frame 0, background black
    camera: CameraSpec,
    supersample: int = 1,
) -> Tensor:  # [3] per-channel factor, in [0.25, 4]
    """How much brighter (per channel) the recording shows the object than its Gaussians' colours
    render: least squares over the pixels both cover. A scene's light and exposure scale the
    colours (our plain renders: 1); without it the whole colour difference would count as misfit,
    raising the error floor and flattening every profile (the realistic look's shading did)."""
    rgb, alpha = render_compared(gaussians.map(lambda t: t[None]), camera, supersample)
    rendered, alpha = rgb[0], alpha[0]
    both = (alpha > 0.5) & (frame.amax(-1) > 0)
    if int(both.sum()) < MIN_GAIN_PIXELS:
        return torch.ones(3)
    seen, made = frame[both].double(), rendered[both].double()
    gain = (seen * made).sum(0) / (made * made).sum(0).clamp_min(1e-12)
    return gain.clamp(0.25, 4.0).float()


def scaled_colours(gaussians: Gaussians, gain: Tensor) -> Gaussians:
    """The Gaussians with their colours multiplied by ``gain`` [3] (clamped to [0, 1])."""
    colours = (gaussians.colors * gain.to(gaussians.sh0)).clamp(0, 1)
    return replace(gaussians, sh0=(colours - 0.5) / SH_C0)


def temperature_for(
    pixels: int,
    supersample: int = 1,
    products: tuple[float, float, float] | None = None,  # τ·pixels at REFERENCE_PIXELS
    rebuilt: bool = False,  # a rebuilt asset (predicted or given shape): its own law
) -> tuple[float, float, float]:
    """τ of each observable's profile posterior (log k/m, log d/m, f) for a compared view of
    ``pixels`` pixels (≥ 1), rendered ``supersample``× larger (:func:`supersampling`; > 1: × the
    fine factors): products / REFERENCE_PIXELS × (REFERENCE_PIXELS / pixels)^exponent, with
    TEMPERATURE_PIXELS, TEMPERATURE_EXPONENT and FINE_TEMPERATURE on a sample's own asset, the
    REBUILT_ ones on a rebuilt asset."""
    if rebuilt:
        own, exponent, fine = (
            REBUILT_TEMPERATURE_PIXELS, REBUILT_TEMPERATURE_EXPONENT, REBUILT_FINE_TEMPERATURE
        )  # fmt: skip
    else:
        own, exponent, fine = TEMPERATURE_PIXELS, TEMPERATURE_EXPONENT, FINE_TEMPERATURE
    factors = fine if supersample > 1 else (1.0, 1.0, 1.0)
    shrink = (REFERENCE_PIXELS / max(pixels, 1)) ** exponent
    return tuple(
        product / REFERENCE_PIXELS * shrink * factor
        for product, factor in zip(products or own, factors, strict=True)
    )


def profile_quantiles(
    values: Tensor,  # [P] grid along one observable (any order)
    errors: Tensor,  # [P] the photometric error at each
    bounds: tuple[float, float],  # the observable's reachable range
    temperature: float,
    quantiles: tuple[float, ...] = QUANTILES,
    prior: tuple[float, float] | None = None,  # (centre, σ) of a normal prior; None: flat
    points: int = 512,
) -> list[float]:
    """Quantiles of the posterior ∝ exp(−(E − E_min) / (τ·E_min)) · prior along a profile, with E
    interpolated linearly between the grid values and held flat beyond them, over ``bounds``. A
    flat profile gives the prior's quantiles (the flat prior's, or the normal's cut to the
    bounds); a sharp one, a narrow interval around its minimum."""
    order = values.argsort()
    v, e = values[order].double(), errors[order].double()
    line = torch.linspace(bounds[0], bounds[1], points, dtype=torch.float64)
    index = torch.searchsorted(v, line).clamp(1, len(v) - 1)
    left, right = v[index - 1], v[index]
    share = ((line - left) / (right - left).clamp_min(1e-12)).clamp(0.0, 1.0)
    energy = e[index - 1] + share * (e[index] - e[index - 1])
    best = float(e.min())
    log_weight = -(energy - energy.min()) / (temperature * max(best, 1e-12))
    if prior is not None:
        centre, sigma = prior
        log_weight = log_weight - 0.5 * ((line - centre) / max(sigma, 1e-9)) ** 2
    weight = torch.exp(log_weight - log_weight.max())
    cdf = weight.cumsum(0) / weight.sum()
    at = torch.searchsorted(cdf, torch.tensor(quantiles, dtype=cdf.dtype)).clamp_max(points - 1)
    return line[at].tolist()


def profile_interval(
    values: Tensor,  # [P] grid along one observable (any order)
    errors: Tensor,  # [P] the photometric error at each
    bounds: tuple[float, float],  # the observable's reachable range
    temperature: float,
    quantiles: tuple[float, float] = QUANTILES,
    points: int = 512,
) -> tuple[float, float]:
    """The (lo, hi) quantiles of the profile posterior with a flat prior over ``bounds``
    (:func:`profile_quantiles`)."""
    low, high = profile_quantiles(values, errors, bounds, temperature, quantiles, points=points)
    return low, high


def network_intervals(centre: Tensor, sigma: Tensor) -> dict[str, list[float]]:
    """The network's own 10–90 % intervals: centre ± 1.2816 σ ([3] each: log k/m, log d/m, f),
    cut to the reachable range (:func:`observable_bounds`)."""
    bounds = observable_bounds()
    low = torch.maximum(centre.double() - Z_10_90 * sigma.double(), bounds[:, 0])
    high = torch.minimum(centre.double() + Z_10_90 * sigma.double(), bounds[:, 1])
    return {n: [float(lo), float(hi)] for n, lo, hi in zip(OBSERVABLES, low, high, strict=True)}


def search(
    asset: Asset,
    frames: Tensor,  # [T, H, W, 3] in [0, 1] (T ≥ 2), the recording's frames 0..T−1
    camera: CameraSpec,  # the recording's camera
    resolution: int = 64,  # longest side of the comparison (frames are area-averaged down)
    spans: tuple[float, ...] = SPANS,
    candidates: int = CANDIDATES,
    profiles: bool = True,  # stage 2: global check and intervals
    temperature: float | tuple[float, float, float] | None = None,  # of the intervals, one or
    # one per observable; None: temperature_for(compared pixels, supersampling)
    masks: Tensor | None = None,  # [T, H, W] the object's masks: compare only around them
    temperature_scale: float = 1.0,  # × the default temperature (predicted geometry: wider)
    rebuilt: bool = False,  # a rebuilt asset (predicted or given shape): τ by its own law
    fine_temperature: bool = True,  # × FINE_TEMPERATURE when supersampled (default temperature)
    motion: Tensor | None = None,  # [6] initial (linear m/s, angular rad/s): searched with them
    silhouette_weight: float = 0.0,  # × the silhouettes' squared error, added (needs masks)
    prior_sigma: Tensor | None = None,  # [3] σ of the network's belief, centred on the start
    ground: bool = False,  # the ground's height searched too (a camera read from the video)
) -> tuple[Asset, dict]:
    """Coordinate search from the asset's attributes, then profiles → (asset with the best, history
    dict with ``intervals`` {observable: [lo, hi]} when ``profiles``).

    Without ``prior_sigma`` each observable's interval is its profile posterior under a flat prior
    and its value the best fit (the start where the profile is too flat to tell). With it, the
    posterior is the profile's times the network's normal belief N(start, σ²): its median is the
    value and its 10–90 % the interval — the network's answer where the recording shows little,
    the fit's where it shows much. "undetermined" always says what the recording alone shows."""
    if frames.dim() != 4 or frames.shape[0] < 2 or frames.shape[-1] != 3:
        raise ValueError(f"frames: expected [T ≥ 2, H, W, 3], got {list(frames.shape)}")
    if candidates < 3 or candidates % 2 == 0:
        raise ValueError(f"candidates: expected an odd number ≥ 3, got {candidates}")
    started = time.perf_counter()
    window = None if masks is None else object_window(masks)
    recorded_width = frames.shape[2]
    silhouettes = None
    if masks is not None and silhouette_weight > 0:
        both = torch.cat([frames, masks[..., None].to(frames)], -1)
        both, camera = comparison_view(both, camera, resolution, window)
        frames, silhouettes = both[..., :3], both[..., 3]
    else:
        frames, camera = comparison_view(frames, camera, resolution, window)
    recorded_scale = (window[2] if window else recorded_width) / frames.shape[2]
    supersample = supersampling(asset.gaussians, camera, recorded_scale)
    gain = lighting_gain(asset.gaussians, frames[0], camera, supersample)
    compared = replace(asset, gaussians=scaled_colours(asset.gaussians, gain))
    size = list(frames.shape[1:3])
    if temperature is None:
        pixels, compared_supersample = size[0] * size[1], supersample if fine_temperature else 1
        temperature = tuple(
            t * temperature_scale
            for t in temperature_for(pixels, compared_supersample, rebuilt=rebuilt)
        )
    elif isinstance(temperature, (int, float)):
        temperature = (float(temperature),) * 3
    bounds = observable_bounds()
    start = observables(asset.physics)
    names = OBSERVABLES
    # the linear velocity is searched in the camera's axes (across the view: well seen; along
    # it: barely), the spin in the world's
    rotation = camera.world_to_cam[:3, :3].double()  # world → camera

    def to_world(values: Tensor) -> Tensor:  # [B, 3 or 9], motion's velocity in camera axes
        if values.shape[1] == 3:
            return values
        return torch.cat([values[:, :3], values[:, 3:6] @ rotation, values[:, 6:]], 1)

    span_scales = list(SPAN_SCALES[:3])
    across = set()  # the motion's coordinates searched only at ACROSS_VIEW_SPANS
    if motion is not None:
        bounds = torch.cat([bounds, MOTION_BOUNDS])
        motion = motion.double()
        start = torch.cat([start, rotation @ motion[:3], motion[3:]])
        names = OBSERVABLES + MOTION_NAMES
        span_scales, across = list(SPAN_SCALES), {3, 4}
    physical = len(start)  # the columns photometric_errors reads as observables and motion
    if ground:  # the last coordinate: metres the ground is lowered by
        limits = torch.tensor([[-GROUND_RANGE_M, GROUND_RANGE_M]], dtype=torch.float64)
        bounds = torch.cat([bounds, limits])
        start = torch.cat([start, torch.zeros(1, dtype=torch.float64)])
        names = (*names, "ground_lowered_m")
        span_scales.append(GROUND_SPAN_SCALE)
    current = torch.maximum(torch.minimum(start, bounds[:, 1]), bounds[:, 0])
    half = candidates // 2  # offsets −1..1 with an exact 0 at the centre (the current value)
    grid = torch.arange(-half, half + 1, dtype=torch.float64) / half
    rounds = []
    best_error = math.inf

    def step(i: int, offsets: Tensor, centre_at: int) -> tuple[Tensor, Tensor]:
        """Try ``current`` with observable i moved by ``offsets`` (``offsets[centre_at]`` = 0);
        keep the best → (the values tried, their errors)."""
        nonlocal current, best_error
        trial = current.repeat(len(offsets), 1)
        trial[:, i] = (current[i] + offsets).clamp(*bounds[i].tolist())
        errors = photometric_errors(
            compared, frames, camera, to_world(trial[:, :physical]), silhouettes=silhouettes,
            silhouette_weight=silhouette_weight, supersample=supersample,
            lowered=trial[:, physical] if ground else None,
        )  # fmt: skip
        pick = int(errors.argmin())
        if not errors[pick] < errors[centre_at] * (1.0 - TIE):
            pick = centre_at  # the current value: kept unless another is clearly better
        current, best_error = trial[pick].clone(), float(errors[pick])
        rounds.append(
            {
                "observable": names[i],
                "values": trial[:, i].tolist(),
                "errors": errors.tolist(),
            }
        )
        return trial[:, i], errors

    def coordinate_search(spans_now, motion_too=True):
        for span in spans_now:
            for i in range(len(current) if motion_too else 3):
                if i not in across or span in ACROSS_VIEW_SPANS:
                    step(i, grid * span * span_scales[i], centre_at=half)

    def profile_pass() -> tuple[bool, list[tuple[Tensor, Tensor]]]:
        """One profile per observable (the others at their best); True if one moved the best."""
        local = torch.tensor(PROFILE_LOCAL, dtype=torch.float64) * spans[-1]
        before, found = current.clone(), []
        for i in range(3):
            wide = torch.linspace(*bounds[i].tolist(), PROFILE_POINTS, dtype=torch.float64)
            zero = torch.zeros(1, dtype=torch.float64)
            found.append(step(i, torch.cat([zero, local * SPAN_SCALES[i], wide - current[i]]), 0))
        return bool((current != before).any()), found

    coordinate_search(spans)
    intervals, profile, undetermined = None, None, []
    if profiles:
        moved, found = profile_pass()
        if moved:  # a better basin than the start's: search it finely, profile again
            coordinate_search(spans[1:], motion_too=False)
            moved, found = profile_pass()
        intervals = {
            name: list(profile_interval(v, e, tuple(bounds[i].tolist()), temperature[i]))
            for i, (name, (v, e)) in enumerate(zip(OBSERVABLES, found, strict=True))
        }
        prior_width = (QUANTILES[1] - QUANTILES[0]) * (bounds[:, 1] - bounds[:, 0])
        for i, (low, high) in enumerate(intervals.values()):
            if high - low >= UNDETERMINED * float(prior_width[i]):
                undetermined.append(OBSERVABLES[i])
                current[i] = start[i]
        if prior_sigma is not None:  # the network's belief × the profile: median and 10–90 %
            for i, (name, (v, e)) in enumerate(zip(OBSERVABLES, found, strict=True)):
                low, middle, high = profile_quantiles(
                    v, e, tuple(bounds[i].tolist()), temperature[i],
                    (QUANTILES[0], 0.5, QUANTILES[1]),
                    prior=(float(start[i]), float(prior_sigma[i])),
                )  # fmt: skip
                intervals[name] = [low, high]
                current[i] = middle
        profile = {
            name: {"values": v.tolist(), "errors": e.tolist()}
            for name, (v, e) in zip(OBSERVABLES, found, strict=True)
        }
    # only what moved: exp(log(k/m))·m would not give back k to the last bit
    best = {n: float(v[0]) for n, v in attributes_of(current[None, :3], asset.physics.mass).items()}
    moved = (current[:3] != start[:3]).tolist()
    mass_moved = best["mass"] != asset.physics.mass
    changed = {"mass": mass_moved, "stiffness": moved[0] or mass_moved,
               "damping": moved[1] or mass_moved, "friction": moved[2]}  # fmt: skip
    found = {name: best[name] for name, yes in changed.items() if yes}
    history = {
        "method": "coordinate search + profiles (pipeline/search.py)",
        "start": dict(zip(OBSERVABLES, start[:3].tolist(), strict=True)),
        "found": dict(zip(OBSERVABLES, current[:3].tolist(), strict=True)),
        "initial_motion": None
        if motion is None
        else to_world(current[None, :physical])[0, 3:].tolist(),
        # metres the ground was lowered by (a camera read from the video), None: not searched
        "ground_lowered_m": float(current[physical]) if ground else None,
        "error": best_error,
        "lighting_gain": [round(float(g), 4) for g in gain],  # rendered colours × this
        "intervals": intervals,  # 10–90 % of the profile posterior (natural logs of SI ratios)
        "undetermined": undetermined,  # what the recording alone does not show
        "profiles": profile,  # the last profile of each observable
        "temperature": list(temperature),  # τ of each observable's posterior
        "network_sigma": None if prior_sigma is None else [float(x) for x in prior_sigma],
        "rounds": rounds,
        "render_size": size,
        "supersample": supersample,  # rendered this many times larger, then averaged
        "window": window,  # (left, top, width, height) of the recording compared; None: all
        "seconds": round(time.perf_counter() - started, 2),
    }
    if ground:
        found["ground_height"] = asset.physics.ground_height - float(current[physical])
    result = replace(asset, physics=replace(asset.physics, **found))
    if motion is not None:
        found_motion = to_world(current[None, :physical])[0, 3:].to(asset.x0)
        result = replace(result, v0=rigid_velocity(asset.x0, found_motion[:3], found_motion[3:]))
    return result, history
