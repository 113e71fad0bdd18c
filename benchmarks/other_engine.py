"""Recordings from another engine: drops simulated and rendered by pybullet, read as a user's
(docs/usage.md#recordings-from-another-engine-pybullet).

Every other number in docs/ is on this project's own renders. Here the physics (pybullet's rigid
bodies: no springs, its own contact and friction), the renderer (pybullet's TinyRenderer: flat
shading, its own shadow map, no anti-aliasing of its own) and the scene (a checker or textured
floor, a textured wall, a light from anywhere above) are not ours. Rendered at 2× and
area-averaged, with sensor noise and H.264 at the size asked.

``render OUT --clips N`` writes, per clip ``OUT/NNNN/``: ``video.mp4`` (what a user brings),
``camera.json`` (the true camera, reconphys's format), ``masks.npz`` (the true masks [T, H, W]:
pybullet's segmentation at 2×, ≥ half a pixel's area; with ``--renderer mitsuba`` Mitsuba's own
silhouettes, pybullet's kept beside as ``pybullet``) and ``truth.json`` (frame 0's pose and
velocity, the object's lowest point in frame 0, the first contact). Objects: the 40 pybullet
meshes that are ``data/pyb``'s test split (held out of every network's training), scaled to
0.1–0.6 m; half are released from rest, half tossed (≤ 1 m/s sideways, −0.5–1 m/s up, ≤ 2 rad/s).

``measure OUT`` reads each clip as ``predict`` does (the mp4 alone; the camera file only for the
errors) and prints: the mask segmenter's IoU with the true masks; the camera read from the video
(45° assumed; and from the true masks with the true field of view) — scale error and drop-height
error as benchmarks/realistic_input.py defines them; then ``predict --no-refine`` (the shipped
segmenter) on the mp4 alone and again with the camera file: refusals, the initial velocity in
the camera's axes against the truth and, for clips released from rest, how many come back over
0.1 m/s; seconds a clip. ``--search`` runs predict's default path (the physics fitted to the
recording) instead, ``--true-masks`` adds a third run with pybullet's own masks (``--masks``)
and the camera file.

``render --soft`` drops pybullet's deformable bodies instead (a mass-spring on the mesh's edges,
with bending springs, from rest; SOFT_MESHES, the pybullet_data meshes its renderer draws right
that way, stiffness and damping log-uniform); ``measure`` then also says whether the physics
orders pybullet's springs (Spearman's ρ of the log k/m and log d/m read against its log
stiffness / mass and log damping / mass, over all clips and within each mesh).

``render --renderer mitsuba`` draws the same rigid drops with Mitsuba 3's path tracer instead of
TinyRenderer (``pip install mitsuba``; soft shadows, bounced light, an exposure and the sRGB
curve; mitsuba_look.py), ``--spp`` its samples a pixel: a look no network here trained on.
Running ``render`` again into the same folder keeps the clips already there (their random draws
made again, so the clips after them come out the same) and renders the rest.

    python benchmarks/other_engine.py render data/engine_pyb --clips 40 --size 128x128
    python benchmarks/other_engine.py render data/mitsuba_pyb --clips 40 --size 128x128 \
        --renderer mitsuba --seed 61
    python benchmarks/other_engine.py measure data/engine_pyb
    python benchmarks/other_engine.py render data/engine_soft --clips 42 --seed 31 --soft
    python benchmarks/other_engine.py measure data/engine_soft --search --true-masks
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import shutil
import tempfile
import time
from pathlib import Path

import imageio.v3 as imageio
import numpy as np
import torch

FRAME_DT = 0.03  # s, the project's frame interval (docs/design.md#conventions)
FRAMES = 30
SUBSTEPS = 10  # pybullet steps a frame
SOFT_SUBSTEPS = 20  # for its deformable (mass-spring) bodies
SOFT_STIFFNESS = (3.0, 1000.0)  # springElasticStiffness, log-uniform: collapses … barely squashes
SOFT_DAMPING = (0.01, 1.0)  # springDampingStiffness, log-uniform
# pybullet_data meshes its TinyRenderer draws right as deformable bodies (the random_urdfs ones
# come out as triangles across the frame)
SOFT_MESHES = (
    "bunny.obj",
    "duck.obj",
    "soccerball.obj",
    "sphere_smooth.obj",
    "torus/torus_textured.obj",
    "cube.obj",
)
SUPERSAMPLE = 2  # rendered at 2× and area-averaged (TinyRenderer does not anti-alias)
TEST_MESHES = "data/pyb"  # its test split's meshes: held out of every network's training
TEXTURES = ("checker_blue.png", "checker_grid.jpg", "tex256.png", "uvmap.png", "cube.png")


def _training_meshes(count: int, exclude: list[str], seed: int) -> list[str]:
    """``count`` of the wheel's ``random_urdfs`` meshes drawn by ``seed``, none that an
    ``exclude`` entry names (train-masks' ``--exclude``: a list file or a dataset's test split):
    drops for training the segmenter on another engine's look, its held-out meshes kept out."""
    import pybullet_data

    from reconphys.assets.mesh import pybullet_mesh_paths
    from reconphys.train.masks import held_out_meshes

    root = Path(pybullet_data.getDataPath())
    held_out = set().union(*map(held_out_meshes, exclude))
    names = [str(m.relative_to(root)) for m in pybullet_mesh_paths()]
    names = [n for n in names if n.startswith("random_urdfs/") and n not in held_out]
    rng = np.random.default_rng([seed, 1])
    return [names[i] for i in sorted(rng.choice(len(names), min(count, len(names)), False))]


def _test_meshes(data: str) -> list[str]:
    """The pybullet meshes of dataset ``data``'s test split."""
    manifest = json.loads((Path(data) / "manifest.json").read_text())
    names = sorted({s["object"] for s in manifest["samples"] if s.get("split") == "test"})
    if not names:
        raise SystemExit(f"{data}: no test split of pybullet meshes")
    return names


def _view_matrix_gl(world_to_cam: np.ndarray) -> list[float]:
    """OpenCV world→camera [4, 4] → pybullet's column-major OpenGL view matrix."""
    return (np.diag([1.0, -1.0, -1.0, 1.0]) @ world_to_cam).T.reshape(-1).tolist()


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:  # [4, 4] OpenCV
    from reconphys.render.cameras import look_at

    return look_at(torch.from_numpy(eye), torch.from_numpy(target)).numpy()


def _area_average(image: np.ndarray, factor: int) -> np.ndarray:
    h, w = image.shape[0] // factor, image.shape[1] // factor
    return image.reshape(h, factor, w, factor, *image.shape[2:]).mean((1, 3))


def _soft_vertices(p, body: int) -> np.ndarray:  # [N, 3] a deformable body's nodes, world
    return np.asarray(p.getMeshData(body, -1, flags=p.MESH_DATA_SIMULATION_MESH)[1])


def _render_clip(
    p,
    rng: np.random.Generator,
    mesh: str,
    width: int,
    height: int,
    soft: bool = False,
    textures: tuple[str, ...] = TEXTURES,
    renderer: str = "tiny",
    spp: int = 32,  # Mitsuba's samples a pixel
    draw_only: bool = False,  # Mitsuba's random choices drawn, its frames not rendered
    sky_share: float = 0.0,  # Mitsuba's clips lit by a sky (mitsuba_look.draw_look)
) -> dict | None:
    """One drop; None when the object leaves the frame or touches its border (drawn again).
    ``soft``: the mesh as pybullet's mass-spring deformable body (a spring on every edge and
    bending springs; stiffness and damping drawn from SOFT_STIFFNESS, SOFT_DAMPING), released
    from rest. ``renderer="mitsuba"``: the frames path-traced by Mitsuba instead
    (mitsuba_look.py; rigid drops), the masks still pybullet's."""
    import pybullet_data

    from reconphys.assets.mesh import load_mesh

    data = Path(pybullet_data.getDataPath())
    substeps = SOFT_SUBSTEPS if soft else SUBSTEPS
    if soft:  # the mesh's nodes as pybullet reads them (unit scale, at the origin)
        p.resetSimulation(p.RESET_USE_DEFORMABLE_WORLD)
        unit = _soft_vertices(p, p.loadSoftBody(str(data / mesh), useMassSpring=1))
    p.resetSimulation(p.RESET_USE_DEFORMABLE_WORLD if soft else 0)
    p.setGravity(0, 0, -9.81)
    p.setTimeStep(FRAME_DT / substeps)
    plane = p.loadURDF(str(data / "plane.urdf"))
    look = {"floor": textures[rng.integers(len(textures))], "wall": None, "object": None}
    floor_texture = p.loadTexture(str(data / look["floor"]))
    p.changeVisualShape(
        plane, -1, textureUniqueId=floor_texture, rgbaColor=[*rng.uniform(0.5, 1.0, 3), 1]
    )
    friction = float(rng.uniform(0.2, 1.0))
    p.changeDynamics(plane, -1, lateralFriction=1.0, restitution=float(rng.uniform(0.0, 0.5)))

    # the object: one of the held-out meshes, its largest side 0.1–0.6 m
    urdf = data / mesh.replace(".obj", ".urdf")
    if soft:
        vertices = unit
    else:
        loaded = load_mesh(data / mesh)
        vertices = np.asarray(loaded.vertices) * 0.015  # the URDFs' mesh scale
    extent = float((vertices.max(0) - vertices.min(0)).max())
    size = float(math.exp(rng.uniform(math.log(0.1), math.log(0.6))))
    scaling = size / extent
    vertices = vertices * scaling
    orientation = p.getQuaternionFromEuler(rng.uniform(-math.pi, math.pi, 3).tolist())
    rotation = np.array(p.getMatrixFromQuaternion(orientation)).reshape(3, 3)
    lowest_below = -float((vertices @ rotation.T)[:, 2].min())
    from_rest = soft or bool(rng.random() < 0.5)
    if from_rest:
        velocity, spin = np.zeros(3), np.zeros(3)
    else:
        heading = rng.uniform(0, 2 * math.pi)
        speed = rng.uniform(0.0, 1.0)
        velocity = np.array(
            [speed * math.cos(heading), speed * math.sin(heading), rng.uniform(-0.5, 1.0)]
        )
        spin = rng.normal(size=3)
        spin *= rng.uniform(0.0, 2.0) / max(np.linalg.norm(spin), 1e-9)
    # first touch 5–10 frames after the release (with the vertical velocity)
    t_touch = rng.uniform(5, 10) * FRAME_DT
    drop = velocity[2] * t_touch + 0.5 * 9.81 * t_touch**2
    if drop < 0.03:
        return None
    centre0 = np.array([0.0, 0.0, drop + lowest_below])
    mass = float(rng.uniform(0.05, 2.0))
    springs = None
    if soft:  # its bounding box's centre over the origin, its lowest node `drop` up
        turned = vertices @ rotation.T
        base = centre0 - np.array([*(turned.max(0) + turned.min(0))[:2] / 2, 0.0])
        springs = {
            "stiffness": float(math.exp(rng.uniform(*np.log(SOFT_STIFFNESS)))),
            "damping": float(math.exp(rng.uniform(*np.log(SOFT_DAMPING)))),
        }
        body = p.loadSoftBody(
            str(data / mesh),
            basePosition=base.tolist(),
            baseOrientation=orientation,
            scale=scaling,
            mass=mass,
            useMassSpring=1,
            useBendingSprings=1,
            useNeoHookean=0,
            springElasticStiffness=springs["stiffness"],
            springDampingStiffness=springs["damping"],
            springDampingAllDirections=1,
            useSelfCollision=0,
            frictionCoeff=friction,
            useFaceContact=1,
            collisionMargin=0.002,
        )
        p.setGravity(0, 0, 0)  # one step at rest: TinyRenderer draws a deformable body's
        p.stepSimulation()  # nodes only after the first step
        p.setGravity(0, 0, -9.81)
    else:
        body = p.loadURDF(
            str(urdf), centre0.tolist(), orientation, globalScaling=scaling, useFixedBase=False
        )
        inertia = mass * size**2 / 12.0
        p.changeDynamics(
            body,
            -1,
            mass=mass,
            localInertiaDiagonal=[inertia] * 3,
            lateralFriction=friction,
            restitution=float(rng.uniform(0.0, 0.5)),
            linearDamping=0.0,
            angularDamping=0.0,
        )
        p.resetBaseVelocity(body, velocity.tolist(), spin.tolist())

    # the camera: a vertical field of view 35–55°, 5–30° down, the object 12–35 % of the
    # frame's height at its release, aimed between the release and the ground, off-centre
    fov = float(rng.uniform(35.0, 55.0))
    pitch = math.radians(rng.uniform(5.0, 30.0))
    share = rng.uniform(0.12, 0.35)
    distance = size / (share * 2 * math.tan(math.radians(fov) / 2))
    azimuth = rng.uniform(0, 2 * math.pi)
    target = np.array([0.0, 0.0, 0.5 * centre0[2]]) + rng.normal(scale=0.1 * distance, size=3) * [
        1,
        1,
        0.3,
    ]
    back = np.array(
        [math.cos(azimuth) * math.cos(pitch), math.sin(azimuth) * math.cos(pitch), math.sin(pitch)]
    )
    eye = target + distance * back
    if eye[2] < 0.05:
        return None
    world_to_cam = _look_at(eye, target)
    # a textured wall 1–3 m behind the drop, facing the camera
    wall_at = -back * np.array([1, 1, 0]) / max(math.cos(pitch), 1e-6) * rng.uniform(1.0, 3.0)
    wall_shape = p.createVisualShape(
        p.GEOM_BOX, halfExtents=[0.02, 6.0, 4.0], rgbaColor=[*rng.uniform(0.3, 1.0, 3), 1]
    )
    wall = p.createMultiBody(
        baseMass=0,
        baseVisualShapeIndex=wall_shape,
        basePosition=[float(wall_at[0]), float(wall_at[1]), 4.0],
        baseOrientation=p.getQuaternionFromEuler([0, 0, azimuth]),
    )
    if rng.random() < 0.7:
        look["wall"] = textures[rng.integers(len(textures))]
        wall_texture = p.loadTexture(str(data / look["wall"]))
        p.changeVisualShape(wall, -1, textureUniqueId=wall_texture)
    if rng.random() < 0.5:  # the mesh's own colour, else a texture on it
        look["object"] = textures[rng.integers(len(textures))]
        object_texture = p.loadTexture(str(data / look["object"]))
        p.changeVisualShape(body, -1, textureUniqueId=object_texture)

    light = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(1.0, 3.0)])
    projection = p.computeProjectionMatrixFOV(fov, width / height, 0.01, 50.0)
    view = _view_matrix_gl(world_to_cam)
    ambient, diffuse = float(rng.uniform(0.3, 0.7)), float(rng.uniform(0.3, 0.7))
    frames, masks, lowest, centres, poses = [], [], [], [], []
    contact_frame = None
    for t in range(FRAMES):
        if t:
            for _ in range(substeps):
                p.stepSimulation()
        if soft:
            world = _soft_vertices(p, body)  # [N, 3]
            if not np.isfinite(world).all():
                return None
            touching = world[:, 2].min() < 0.005
        else:
            position, quaternion = p.getBasePositionAndOrientation(body)
            rotation = np.array(p.getMatrixFromQuaternion(quaternion)).reshape(3, 3)
            # the URDFs' inertial origin is the link's: the base pose is the mesh frame's
            world = vertices @ rotation.T + np.array(position)  # [N, 3]
            touching = bool(t and p.getContactPoints(body, plane))
        if contact_frame is None and touching:
            contact_frame = t
        poses.append(world)
        lowest.append(world[world[:, 2].argmin()].tolist())
        centres.append(((world.max(0) + world.min(0)) / 2).tolist())
        _, _, rgba, _, segmentation = p.getCameraImage(
            width * SUPERSAMPLE,
            height * SUPERSAMPLE,
            viewMatrix=view,
            projectionMatrix=projection,
            lightDirection=light.tolist(),
            shadow=1,
            lightAmbientCoeff=ambient,
            lightDiffuseCoeff=diffuse,
            lightSpecularCoeff=0.1,
            renderer=p.ER_TINY_RENDERER,
        )
        rgb = np.asarray(rgba, dtype=np.float64).reshape(height * SUPERSAMPLE, -1, 4)[..., :3]
        object_px = np.asarray(segmentation).reshape(height * SUPERSAMPLE, -1) == body
        frames.append(_area_average(rgb / 255.0, SUPERSAMPLE))
        masks.append(_area_average(object_px.astype(np.float64), SUPERSAMPLE) >= 0.5)
    masks = np.stack(masks)
    border = masks[:, 0].any() or masks[:, -1].any() or masks[:, :, 0].any()
    if border or masks[:, :, -1].any() or not masks.reshape(FRAMES, -1).any(1).all():
        return None
    pybullet_masks, agreement = None, None
    if renderer == "mitsuba":  # the same drop, path-traced (mitsuba_look.py)
        import mitsuba_look

        look = {"floor": None, "wall": None, "object": None}
        drawn = mitsuba_look.draw_look(rng, textures, sky_share)
        faces = np.asarray(loaded.faces)
        args = (world_to_cam, fov, width, height)
        if not draw_only:
            mitsuba_look.check_alignment(masks[0], poses[0], faces, *args)
            frames = mitsuba_look.render_frames(
                drawn, np.stack(poses), faces, *args, wall_at, azimuth, spp
            )
            # the truth is what Mitsuba drew; pybullet's masks of the same poses kept beside
            pybullet_masks = masks
            masks = mitsuba_look.silhouettes(np.stack(poses), faces, *args)
            from common import mean_mask_iou

            agreement = mean_mask_iou(torch.from_numpy(masks), torch.from_numpy(pybullet_masks))
        look.update(floor=drawn["floor"], wall=drawn["wall"], mitsuba=drawn)
    K = np.array(
        [
            [0.5 * height / math.tan(math.radians(fov) / 2), 0, width / 2],
            [0, 0.5 * height / math.tan(math.radians(fov) / 2), height / 2],
            [0, 0, 1],
        ]
    )
    return {
        "frames": np.stack(frames),
        "masks": masks,
        "K": K,
        "world_to_cam": world_to_cam,
        "truth": {
            "object": mesh,
            "size_m": size,
            "fov_deg": fov,
            "pitch_deg": math.degrees(pitch),
            "released_from_rest": from_rest,
            "initial_velocity_m_s": velocity.tolist(),
            "angular_velocity_rad_s": spin.tolist(),
            "centre_m": centres,  # [T, 3] the mesh's bounding-box centre, world
            "lowest_point_m": lowest,  # [T, 3] its lowest vertex, world
            "first_contact_frame": contact_frame,
            "drop_height_m": lowest[0][2],
            "mass_kg": mass,
            "friction": friction,
            "textures": look,  # pybullet_data images on the floor, the wall, the object
            # pybullet's mass-spring body: its spring stiffness and damping (None: rigid)
            "springs": springs,
            # Mitsuba's clips: their masks are its silhouettes; pybullet's agree to this IoU
            "pybullet_masks_iou": agreement,
        },
        "pybullet_masks": pybullet_masks,
    }


def render(args) -> None:
    import pybullet as p

    from reconphys.capture import CameraSpec, write_camera
    from reconphys.render.video import write_mp4

    width, height = (int(x) for x in args.size.split("x"))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    textures = tuple(args.textures.split(",")) if args.textures else TEXTURES
    if not set(textures) <= set(TEXTURES):
        raise SystemExit(f"--textures: each one of {', '.join(TEXTURES)}")
    if args.sky_share and args.renderer != "mitsuba":
        raise SystemExit("--sky-share: Mitsuba's renders only")
    if args.soft and args.renderer != "tiny":
        raise SystemExit("--soft: pybullet's TinyRenderer only")
    if args.soft:
        meshes = list(SOFT_MESHES)
    elif args.training_meshes:
        meshes = _training_meshes(args.training_meshes, args.exclude, args.seed)
    else:
        meshes = _test_meshes(args.meshes)
    rng = np.random.default_rng(args.seed)
    client = p.connect(p.DIRECT)
    written, tries = 0, 0
    started = time.perf_counter()
    try:
        while written < args.clips:
            tries += 1
            mesh = meshes[written % len(meshes)]
            folder = out / f"{written:04d}"
            # a clip written by an earlier run of the same command: its draws made again (the
            # clips after it stay the same), Mitsuba's frames not rendered again
            done = (folder / "truth.json").is_file()
            try:
                clip = _render_clip(
                    p,
                    rng,
                    mesh,
                    width,
                    height,
                    args.soft,
                    textures,
                    args.renderer,
                    args.spp,
                    draw_only=done,
                    sky_share=args.sky_share,
                )
            except Exception as e:  # a broken mesh of the wheel's (random_urdfs/168 is one)
                if not args.training_meshes:
                    raise
                print(f"{mesh}: {e}; dropped", flush=True)
                meshes.remove(mesh)
                continue
            if clip is None:
                continue
            noisy = clip["frames"] + rng.normal(
                scale=rng.uniform(0.0, 0.02), size=clip["frames"].shape
            )
            quality = rng.uniform(6, 8)
            if done:
                written += 1
                print(f"{written}/{args.clips} {clip['truth']['object']} (kept)", flush=True)
                continue
            folder.mkdir(exist_ok=True)
            pixels = (np.clip(noisy, 0, 1) * 255 + 0.5).astype(np.uint8)
            write_mp4(folder / "video.mp4", pixels, fps=1 / FRAME_DT, quality=quality)
            camera = CameraSpec(
                torch.from_numpy(clip["K"]),
                torch.from_numpy(clip["world_to_cam"]),
                width,
                height,
            )
            write_camera(folder / "camera.json", camera)
            kept = {} if clip["pybullet_masks"] is None else {"pybullet": clip["pybullet_masks"]}
            np.savez_compressed(folder / "masks.npz", masks=clip["masks"], **kept)
            (folder / "truth.json").write_text(json.dumps(clip["truth"], indent=1) + "\n")
            written += 1
            print(f"{written}/{args.clips} {clip['truth']['object']} ({tries} drawn)", flush=True)
    finally:
        p.disconnect(client)
    print(f"{written} clips in {time.perf_counter() - started:.0f} s")


def _camera_errors(masks, truth, camera, fov_deg, fit_px) -> dict:
    """Scale and drop-height errors of the camera read from ``masks`` (realistic_input's)."""
    from common import camera_read_errors

    from reconphys.capture.calibrate import estimate_camera

    estimate = estimate_camera(masks, FRAME_DT, fov_deg, fit_px)
    centre = torch.tensor(truth["centre_m"][0], dtype=torch.float64)
    lowest = torch.tensor(truth["lowest_point_m"][0], dtype=torch.float64)
    return camera_read_errors(estimate, camera.K, camera.world_to_cam, centre, lowest)


def measure(args) -> None:
    from common import mean_mask_iou

    from reconphys.capture import read_camera
    from reconphys.capture.calibrate import FALL_FIT_PX, SEGMENTER_FALL_FIT_PX
    from reconphys.capture.video import read_video
    from reconphys.errors import InputError
    from reconphys.models.mask_segmenter import load_mask_segmenter, rated_segment_clip

    torch.set_num_threads(2)
    folders = sorted(f for f in Path(args.out).iterdir() if (f / "truth.json").is_file())
    folders = folders[: args.limit] if args.limit else folders
    segmenter = load_mask_segmenter(args.segmenter)
    rows = []
    for folder in folders:
        truth = json.loads((folder / "truth.json").read_text())
        stored = np.load(folder / "masks.npz")
        true_masks = torch.from_numpy(stored["masks"]).float()
        decoded, *_ = read_video(folder / "video.mp4")
        height, width = true_masks.shape[1:]
        frames = torch.from_numpy(decoded[:, :height, :width, :3]).float() / 255
        masks, rating = rated_segment_clip(segmenter, frames, colours=not args.no_colours)
        camera = read_camera(folder / "camera.json", width, height)
        row = {
            "clip": folder.name,
            "object": truth["object"],
            "from_rest": truth["released_from_rest"],
            "iou": mean_mask_iou(masks, true_masks),
            "masks_rating": rating,
        }
        if "pybullet" in stored:  # Mitsuba's clips: against pybullet's masks as well (before)
            pybullet_masks = torch.from_numpy(stored["pybullet"]).float()
            row["iou_pybullet_masks"] = mean_mask_iou(masks, pybullet_masks)
            row["pybullet_masks_iou"] = truth["pybullet_masks_iou"]
        if truth.get("springs"):  # a deformable drop: what the physics should order
            row["springs"] = truth["springs"]
            row["mass_kg"] = truth["mass_kg"]
            row["squash"] = _squash(true_masks, truth["first_contact_frame"])
        for name, used, fov, fit_px in (
            ("camera_true_masks", true_masks, truth["fov_deg"], FALL_FIT_PX),
            ("camera_segmenter", masks, None, SEGMENTER_FALL_FIT_PX),
        ):
            try:
                row[name] = _camera_errors(used, truth, camera, fov, fit_px)
            except InputError as e:
                row[name] = {"refused": str(e)}
        if not args.no_predict:  # the mp4 alone, then with the camera file
            runs = [("predict", {}), ("predict_camera_file", {"camera": folder / "camera.json"})]
            if args.true_masks:  # the engine's own masks as --masks DIR, and the camera file
                masks_dir = Path(tempfile.mkdtemp())
                for t, mask in enumerate(true_masks.numpy() > 0.5):
                    imageio.imwrite(masks_dir / f"{t:03d}.png", (mask * 255).astype(np.uint8))
                runs.append(
                    ("predict_true_masks", {"camera": folder / "camera.json", "masks": masks_dir})
                )
            for name, options in runs:
                row[name] = _predict(folder / "video.mp4", options, truth, camera, args.search)
            if args.true_masks:
                shutil.rmtree(masks_dir)
        rows.append(row)
        print(json.dumps(row), flush=True)
    _report(rows)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")


def _squash(masks: torch.Tensor, contact: int | None) -> float | None:
    """The true silhouette's least height after the first touch over its height in frame 0
    (rows, perspective aside): how much the video shows the object give."""
    rows = (masks > 0.5).any(2)  # [T, H]
    heights = [int(r.nonzero().max() - r.nonzero().min()) + 1 for r in rows]
    return None if contact is None else min(heights[contact:]) / heights[0]


def _predict(video: Path, options: dict, truth: dict, camera, search: bool = False) -> dict:
    """``predict --no-refine`` on ``video`` (``search``: predict's default path, the physics
    fitted to the recording): the initial velocity in the camera's axes (the camera it used,
    and the true one) and the attributes, or the refusal."""
    import reconphys
    from reconphys.errors import InputError

    tic = time.perf_counter()
    try:
        result = reconphys.predict(video, refine=search, **options)
    except InputError as e:
        return {"refused": str(e)}
    velocity = torch.tensor(result.details["initial_velocity"]["linear_m_s"]).double()
    true = torch.tensor(truth["initial_velocity_m_s"], dtype=torch.float64)
    return {
        "velocity_camera_m_s": (
            result.observation.camera.world_to_cam[:3, :3].double() @ velocity
        ).tolist(),
        "true_velocity_camera_m_s": (camera.world_to_cam[:3, :3].double() @ true).tolist(),
        "at_rest": result.details["initial_velocity"]["released_from_rest"],
        "observables": result.observables,
        "search": search,
        "seconds": time.perf_counter() - tic,
    }


PREDICT_RUNS = (
    ("predict", "mp4 alone"),
    ("predict_camera_file", "mp4 + camera file"),
    ("predict_true_masks", "mp4 + the engine's masks + camera file"),
)


def _report(rows: list[dict]) -> None:
    from common import rating_line

    machine = platform.processor() or platform.machine()
    print(f"\n{len(rows)} clips; {machine}, torch {torch.__version__}")
    ious = np.array([r["iou"] for r in rows])
    print(
        f"mask IoU (segmenter): mean {ious.mean():.3f}, median {np.median(ious):.3f}, "
        f"min {ious.min():.3f}, >= 0.9: {(ious >= 0.9).mean():.0%}"
    )
    if all("masks_rating" in r for r in rows):  # rows of runs before the rating have none
        print(rating_line([r["masks_rating"] for r in rows], list(ious)))
    if all("iou_pybullet_masks" in r for r in rows):  # Mitsuba's clips
        print(
            "  the same masks against pybullet's of the same poses: mean "
            f"{np.mean([r['iou_pybullet_masks'] for r in rows]):.3f}; pybullet's against "
            f"Mitsuba's own: {np.mean([r['pybullet_masks_iou'] for r in rows]):.3f}"
        )
    for name in ("camera_true_masks", "camera_segmenter"):
        good = [r[name] for r in rows if "refused" not in r[name]]
        if not good:
            print(f"{name}: all refused")
            continue
        scale = np.abs([g["scale_error"] for g in good])
        ground = np.abs([g["ground_error_m"] for g in good]) * 100
        print(
            f"{name}: |scale error| mean {scale.mean():.1%} (median {np.median(scale):.1%}, "
            f"<= 10 %: {(scale <= 0.1).mean():.0%}); |drop-height error| mean {ground.mean():.1f} "
            f"cm (median {np.median(ground):.1f}, <= 2 cm: {(ground <= 2).mean():.0%}); "
            f"refused {len(rows) - len(good)}"
        )
    for key, label in PREDICT_RUNS:
        _report_predict(rows, key, label)
    if any("springs" in r for r in rows):
        _report_springs(rows)


def _report_springs(rows: list[dict]) -> None:
    """Deformable drops: does the physics order the engine's springs? Spearman's ρ of the
    log k/m and log d/m read against pybullet's log(stiffness / mass) and log(damping / mass),
    over all clips and within each mesh (a mesh's node count sets how a spring's stiffness
    shows, so only the order within a mesh is like for like); beside it, the ρ of the true
    silhouette's squash (a reference: how much the videos show the stiffness)."""
    from scipy.stats import spearmanr

    soft = [r for r in rows if "springs" in r]
    truth = {
        "log_k_over_m": lambda r: math.log(r["springs"]["stiffness"] / r["mass_kg"]),
        "log_d_over_m": lambda r: math.log(r["springs"]["damping"] / r["mass_kg"]),
    }

    def rho(pairs):  # [(truth, read)] → (ρ over all, mean ρ within meshes with 4+ clips, n)
        whole = spearmanr([a for _, a, _ in pairs], [b for _, _, b in pairs]).statistic
        meshes = {m for m, _, _ in pairs}
        within = [
            spearmanr([a for n, a, _ in pairs if n == m], [b for n, _, b in pairs if n == m])
            for m in meshes
            if sum(n == m for n, _, _ in pairs) >= 4
        ]
        inside = np.nanmean([w.statistic for w in within]) if within else float("nan")
        return whole, inside, len(pairs)

    seen = [(r["object"], truth["log_k_over_m"](r), r["squash"]) for r in soft if r["squash"]]
    whole, inside, n = rho(seen)
    print(
        f"deformable drops: {len(soft)}; the true silhouette's squash against log k/m: "
        f"rho {whole:.2f} over all, {inside:.2f} within meshes ({n} clips; 1: the stiffer keeps "
        "more of its height, always)"
    )
    for key, label in PREDICT_RUNS:
        answered = [r for r in soft if key in r and "refused" not in r[key]]
        if not answered:
            continue
        line = f"  {label}: {len(answered)}/{len(soft)} answered;"
        for name, value in truth.items():
            pairs = [(r["object"], value(r), r[key]["observables"][name]) for r in answered]
            whole, inside, _ = rho(pairs)
            line += f" {name} rho {whole:.2f} over all, {inside:.2f} within meshes;"
        print(line)


def _report_predict(rows: list[dict], key: str, what: str) -> None:
    predicted = [r for r in rows if key in r]
    if predicted:
        answered = [r for r in predicted if "refused" not in r[key]]
        how = "predict" if any(r[key].get("search") for r in answered) else "predict --no-refine"
        print(f"{how}, {what}: {len(answered)}/{len(predicted)} answered")
        for label, keep in (("from rest", True), ("moving", False)):
            chosen = [r[key] for r in answered if r["from_rest"] == keep]
            if not chosen:
                continue
            error = np.abs(
                [
                    np.subtract(c["velocity_camera_m_s"], c["true_velocity_camera_m_s"])
                    for c in chosen
                ]
            ).mean(0)
            speeds = [np.linalg.norm(c["velocity_camera_m_s"]) for c in chosen]
            line = (
                f"  {label} ({len(chosen)}): |v error| right/down/along {error.round(3).tolist()}"
            )
            if keep:
                over = sum(s > 0.1 for s in speeds)
                line += f"; read at rest {sum(c['at_rest'] for c in chosen)}, over 0.1 m/s {over}"
            print(line)
        seconds = [r[key]["seconds"] for r in answered]
        if seconds:
            print(f"  {np.mean(seconds):.1f} s a clip")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    make = commands.add_parser("render", help="simulate and render clips with pybullet")
    make.add_argument("out")
    make.add_argument("--clips", type=int, default=40)
    make.add_argument("--seed", type=int, default=0)
    make.add_argument("--size", default="128x128", help="WIDTHxHEIGHT pixels")
    make.add_argument(
        "--soft",
        action="store_true",
        help="deformable (mass-spring) drops from rest of SOFT_MESHES instead of --meshes",
    )
    make.add_argument(
        "--meshes",
        default=TEST_MESHES,
        help="a pybullet dataset whose test split's meshes to drop (default: data/pyb's, held "
        "out of every network; a validation set's to choose a setting)",
    )
    make.add_argument(
        "--training-meshes",
        type=int,
        default=0,
        help="drop this many of the wheel's meshes instead, none of --exclude's (training "
        "clips for train-masks)",
    )
    make.add_argument(
        "--exclude",
        nargs="+",
        default=["configs/masks_held_out.txt"],
        help="with --training-meshes: meshes never drawn (a list file or a dataset's test split)",
    )
    make.add_argument(
        "--textures",
        default="",
        help=f"comma-separated images for the floor, wall and object (default all: {TEXTURES})",
    )
    make.add_argument(
        "--renderer",
        choices=("tiny", "mitsuba"),
        default="tiny",
        help="pybullet's TinyRenderer, or Mitsuba 3's path tracer (pip install mitsuba; rigid "
        "drops; benchmarks/mitsuba_look.py)",
    )
    make.add_argument("--spp", type=int, default=32, help="Mitsuba's samples a pixel")
    make.add_argument(
        "--sky-share",
        type=float,
        default=0.0,
        help="Mitsuba's clips lit by a sky instead of a constant ambient light, half of them "
        "without the wall (training variety; 0 keeps the validation and test renders' draws)",
    )
    read = commands.add_parser("measure", help="read the clips as predict does")
    read.add_argument("out")
    read.add_argument("--limit", type=int, default=None)
    read.add_argument("--no-predict", action="store_true", help="the front end only")
    read.add_argument(
        "--true-masks",
        action="store_true",
        help="also predict with the engine's masks (--masks) and the camera file",
    )
    read.add_argument(
        "--search",
        action="store_true",
        help="predict's default path (the physics fitted to the recording), not --no-refine",
    )
    read.add_argument(
        "--segmenter",
        nargs="+",
        default=None,
        help="weights: one file, or several averaged (default: the shipped ensemble)",
    )
    read.add_argument(
        "--no-colours",
        action="store_true",
        help="the segmenter's masks without the clip's colour model (models/mask_colours.py; "
        "the front end's rows only: predict keeps its default)",
    )
    read.add_argument("--json", default=None, help="write the per-clip rows here")
    args = parser.parse_args()
    render(args) if args.command == "render" else measure(args)


if __name__ == "__main__":
    main()
