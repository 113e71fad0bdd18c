"""A third look for other_engine.py's drops: pybullet's physics, drawn by Mitsuba 3's path tracer
(``other_engine.py render --renderer mitsuba``; ``pip install mitsuba``, its CPU variant).

Neither this project's renderer nor pybullet's: light carried by path tracing (soft shadows from
a round lamp of random size, light bounced off the floor and the wall onto the object), a floor
of pybullet_data's images tiled at a random scale, a wall, an object of one colour — matte or
glossy — and a camera's exposure and sRGB curve. The true masks are Mitsuba's own silhouettes of
the object (:func:`silhouettes`); :func:`check_alignment` first compares frame 0's with
pybullet's mask of the same pose (a camera-convention check).
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np

SPP = 32  # samples a pixel (path tracing is its own anti-aliasing: rendered at the clip's size)
MAX_DEPTH = 4  # light bounces
# Mitsuba's frame-0 silhouette against pybullet's mask (check_alignment)
MAX_CENTROID_OFFSET_PX = 1.0
MAX_AREA_SHARE = 0.25  # of the mask's area, beside a rim of about half a pixel (2·√area px)


def _variant():
    import mitsuba as mi

    if mi.variant() is None:
        mi.set_variant("scalar_rgb")
    return mi


def _to_world(world_to_cam: np.ndarray):
    """OpenCV world→camera [4, 4] → Mitsuba's camera-to-world (its camera: x left, y up)."""
    mi = _variant()
    cam_to_world = np.linalg.inv(world_to_cam) @ np.diag([-1.0, -1.0, 1.0, 1.0])
    return mi.ScalarTransform4f(cam_to_world.tolist())


def _sensor(world_to_cam: np.ndarray, fov: float, width: int, height: int, spp: int, rgba=False):
    return {
        "type": "perspective",
        "fov": fov,
        "fov_axis": "y",
        "to_world": _to_world(world_to_cam),
        "near_clip": 0.01,
        "far_clip": 100.0,
        "film": {
            "type": "hdrfilm",
            "width": width,
            "height": height,
            "pixel_format": "rgba" if rgba else "rgb",
            "rfilter": {"type": "gaussian"},
        },
        "sampler": {"type": "independent", "sample_count": spp},
    }


def draw_look(rng: np.random.Generator, textures: tuple[str, ...], sky_share: float = 0.0) -> dict:
    """The scene's random choices (JSON-ready): floor image, tiling and tint, wall colour or
    image, object colour and gloss, lamp direction, size and strength, ambient light.
    ``sky_share``: the share of clips lit by a sky (:func:`_sky`) instead of the constant
    ambient light, half of them without the wall, so the sky is seen over the floor's horizon
    (0: the draws of the validation and test renders, made before the sky existed)."""
    direction = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(0.7, 3.0)])
    look = {
        "floor": str(textures[rng.integers(len(textures))]),
        "floor_tiles": float(rng.uniform(4.0, 40.0)),  # image repeats over the 20-m floor
        "white_balance": rng.uniform(0.75, 1.0, 3).tolist(),  # the camera's, on every pixel
        "wall": str(textures[rng.integers(len(textures))]) if rng.random() < 0.6 else None,
        "wall_colour": rng.uniform(0.15, 0.9, 3).tolist(),
        "object_colour": rng.uniform(0.05, 0.95, 3).tolist(),
        "object_glossy": bool(rng.random() < 0.5),
        "object_roughness": float(rng.uniform(0.05, 0.4)),
        "lamp_direction": (direction / np.linalg.norm(direction)).tolist(),
        "lamp_radius_m": float(math.exp(rng.uniform(math.log(0.05), math.log(1.5)))),
        "lamp_irradiance": float(rng.uniform(1.0, 4.0)),
        "ambient": float(rng.uniform(0.1, 0.6)),
        "exposure_percentile": float(rng.uniform(97.0, 99.9)),
        "sky": None,
    }
    if sky_share > 0 and rng.random() < sky_share:
        look["sky"] = {
            "zenith": rng.uniform(0.1, 1.0, 3).tolist(),
            "horizon": rng.uniform(0.4, 1.0, 3).tolist(),
            "strength": float(rng.uniform(0.3, 1.2)),
        }
        if rng.random() < 0.5:
            look["wall"], look["no_wall"] = None, True
    return look


def _sky(sky: dict):
    """A sky as Mitsuba's environment light: a latitude-longitude image from the zenith's
    colour to the horizon's (smoothstep in elevation), 0.3 of the horizon's colour below it;
    Mitsuba's y (up) turned onto the world's z."""
    mi = _variant()
    rows, cols = 64, 128
    elevation = np.linspace(0.5, -0.5, rows) * math.pi  # row 0 straight up
    up = np.clip(elevation / (0.5 * math.pi), 0.0, 1.0)[:, None]
    t = up * up * (3 - 2 * up)
    colour = (1 - t) * np.asarray(sky["horizon"]) + t * np.asarray(sky["zenith"])  # [rows, 3]
    colour = np.where((elevation < 0)[:, None], 0.3 * np.asarray(sky["horizon"]), colour)
    image = np.repeat(colour[:, None, :], cols, axis=1) * sky["strength"]
    return {
        "type": "envmap",
        "bitmap": mi.Bitmap(image.astype(np.float32)),
        "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], 90.0),
    }


def _textured(image: str | None, colour: list[float], tiles: float, data: Path) -> dict:
    mi = _variant()
    if image is None:
        return {"type": "diffuse", "reflectance": {"type": "rgb", "value": colour}}
    return {
        "type": "diffuse",
        "reflectance": {
            "type": "bitmap",
            "filename": str(data / image),
            "to_uv": mi.ScalarTransform4f().scale([tiles, tiles, 1.0]),
        },
    }


def _scene(look: dict, data: Path, wall_at: np.ndarray, azimuth: float, object_ply: Path | None):
    mi = _variant()
    T = mi.ScalarTransform4f
    lamp_distance = 8.0
    lamp_at = (np.array(look["lamp_direction"]) * lamp_distance).tolist()
    radius = look["lamp_radius_m"]
    # a sphere of radiance L seen from d away gives the irradiance π·L·(r/d)² facing it
    radiance = look["lamp_irradiance"] * lamp_distance**2 / (math.pi * radius**2)
    if look.get("sky"):
        ambient = _sky(look["sky"])
    else:
        ambient = {"type": "constant", "radiance": {"type": "rgb", "value": look["ambient"]}}
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": MAX_DEPTH},
        "ambient": ambient,
        "lamp": {
            "type": "sphere",
            "center": lamp_at,
            "radius": radius,
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": radiance}},
        },
        "floor": {
            "type": "rectangle",
            "to_world": T().scale([10.0, 10.0, 1.0]),
            "bsdf": _textured(look["floor"], look["wall_colour"], look["floor_tiles"], data),
        },
    }
    if not look.get("no_wall"):
        scene["wall"] = {
            "type": "rectangle",
            # facing the camera (its normal along the wall's offset back towards the drop)
            "to_world": T()
            .translate([float(wall_at[0]), float(wall_at[1]), 4.0])
            .rotate([0, 0, 1], math.degrees(azimuth))
            .rotate([0, 1, 0], 90.0)
            .scale([4.0, 6.0, 1.0]),
            "bsdf": {
                "type": "twosided",
                "bsdf": _textured(look["wall"], look["wall_colour"], 3.0, data),
            },
        }
    if object_ply is not None:
        scene["object"] = {"type": "ply", "filename": str(object_ply), "bsdf": _object_bsdf(look)}
    return scene


def _object_bsdf(look: dict) -> dict:
    colour = {"type": "rgb", "value": look["object_colour"]}
    if look["object_glossy"]:
        return {
            "type": "roughplastic",
            "diffuse_reflectance": colour,
            "alpha": look["object_roughness"],
        }
    return {"type": "diffuse", "reflectance": colour}


def _write_ply(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    import trimesh

    trimesh.Trimesh(vertices, faces, process=False).export(path)


def render_frames(
    look: dict,
    vertices: np.ndarray,  # [T, V, 3] the object's vertices every frame, world, metres
    faces: np.ndarray,  # [F, 3]
    world_to_cam: np.ndarray,  # [4, 4] OpenCV
    fov: float,  # vertical, degrees
    width: int,
    height: int,
    wall_at: np.ndarray,  # [3] the wall's centre on the ground
    azimuth: float,  # radians: the camera's heading about z (the wall faces it)
    spp: int = SPP,
) -> np.ndarray:  # [T, H, W, 3] in [0, 1], sRGB
    """Path-traced frames of the drop: linear light, one exposure for the clip (the
    ``exposure_percentile``-th percentile of frame 0 at 0.95), a white balance, then the sRGB
    curve."""
    mi = _variant()
    data = _pybullet_data()
    linear = []
    with tempfile.TemporaryDirectory() as folder:
        ply = Path(folder) / "object.ply"
        for world in vertices:
            _write_ply(ply, world, faces)
            scene = _scene(look, data, wall_at, azimuth, ply)
            scene["sensor"] = _sensor(world_to_cam, fov, width, height, spp)
            image = np.asarray(mi.render(mi.load_dict(scene), spp=spp), dtype=np.float64)
            linear.append(image[..., :3])
    linear = np.stack(linear) * np.asarray(look["white_balance"])  # [T, H, W, 3]
    exposure = 0.95 / max(float(np.percentile(linear[0], look["exposure_percentile"])), 1e-6)
    return _srgb(np.clip(linear * exposure, 0.0, 1.0))


def silhouettes(
    vertices: np.ndarray,  # [T, V, 3] the object's vertices every frame, world, metres
    faces: np.ndarray,  # [F, 3]
    world_to_cam: np.ndarray,
    fov: float,
    width: int,
    height: int,
) -> np.ndarray:  # [T, H, W] bool: Mitsuba's coverage of the object alone ≥ ½, each frame
    """What Mitsuba draws of the object, frame by frame: the clip's true masks (the frames'
    own outline; pybullet's rasterised masks of the same poses differ by up to a pixel's rim)."""
    mi = _variant()
    drawn = []
    with tempfile.TemporaryDirectory() as folder:
        ply = Path(folder) / "object.ply"
        for world in vertices:
            _write_ply(ply, world, faces)
            scene = {
                "type": "scene",
                "integrator": {"type": "direct"},
                "object": {"type": "ply", "filename": str(ply)},
                "sensor": _sensor(world_to_cam, fov, width, height, 16, rgba=True),
            }
            image = np.asarray(mi.render(mi.load_dict(scene), spp=16), dtype=np.float64)
            drawn.append(image[..., 3] >= 0.5)
    return np.stack(drawn)


def check_alignment(mask: np.ndarray, vertices, faces, world_to_cam, fov, width, height) -> float:
    """How far Mitsuba's frame-0 silhouette's centroid lies from pybullet's mask's [H, W], px;
    SystemExit past MAX_CENTROID_OFFSET_PX or with an area off by more than MAX_AREA_SHARE of
    it plus a half-pixel rim (the two cameras or poses disagree: a convention error). Not the
    IoU: a small object's rim alone takes it to 0.8."""
    drawn = silhouettes(vertices[None], faces, world_to_cam, fov, width, height)[0]
    centroids = [np.argwhere(m).mean(0) if m.any() else np.full(2, np.inf) for m in (drawn, mask)]
    offset = float(np.linalg.norm(centroids[0] - centroids[1]))
    area = float(mask.sum())
    ratio = float(drawn.sum()) / max(area, 1.0)
    tolerance = MAX_AREA_SHARE * area + 2.0 * math.sqrt(area)
    if not (offset <= MAX_CENTROID_OFFSET_PX and abs(float(drawn.sum()) - area) <= tolerance):
        raise SystemExit(
            f"Mitsuba's silhouette of frame 0 lies {offset:.2f} px from pybullet's mask, its "
            f"area ×{ratio:.2f}: the cameras disagree"
        )
    return offset


def _srgb(linear: np.ndarray) -> np.ndarray:
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(linear, 1 / 2.4) - 0.055)


def _pybullet_data() -> Path:
    import pybullet_data

    return Path(pybullet_data.getDataPath())
