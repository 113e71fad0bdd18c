"""Meshes → Gaussians, checked against the analytic geometry of the meshes we build."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
import torch
import trimesh
from PIL import Image

from reconphys.assets.mesh import load_mesh, mesh_to_gaussians, pybullet_mesh_paths
from reconphys.errors import InputError

NUM = 2000
INTERIOR_FRACTION = 0.3
NUM_INTERIOR = round(NUM * INTERIOR_FRACTION)
SIZE = 0.5
BOX_EXTENTS = np.array([0.3, 0.2, 0.1])
BOX_CENTER = np.array([1.0, 2.0, 3.0])


def _split(g):
    means = g.means.double()
    return means[: NUM - NUM_INTERIOR], means[NUM - NUM_INTERIOR :]


def _box_file(tmp_path, suffix=".obj"):
    box = trimesh.creation.box(extents=BOX_EXTENTS)
    box.apply_translation(BOX_CENTER)
    path = tmp_path / f"box{suffix}"
    box.export(path)
    return path


def test_box_samples_lie_on_its_faces_and_inside(tmp_path):
    g = mesh_to_gaussians(_box_file(tmp_path), NUM, seed=0, size=SIZE)
    assert g.num_gaussians == NUM and g.means.dtype == torch.float32
    half = torch.tensor(BOX_EXTENTS / BOX_EXTENTS.max() * SIZE / 2)  # centred, largest side SIZE
    surface, interior = _split(g)
    # On the surface of a box: inside the box, and on at least one face plane.
    assert ((surface.abs() - half).max(dim=-1).values.abs() < 1e-6).all()
    assert (surface.abs() <= half + 1e-6).all()
    assert (interior.abs() < half).all()
    # The samples span the box: every face has samples, the bounding box is the mesh's.
    for axis in range(3):
        assert surface[:, axis].max().item() == pytest.approx(half[axis].item(), abs=1e-6)
        assert surface[:, axis].min().item() == pytest.approx(-half[axis].item(), abs=1e-6)
    # Interior samples fill the volume rather than clumping: every octant gets some.
    octants = ((interior > 0).long() * torch.tensor([1, 2, 4])).sum(dim=-1)
    assert len(torch.unique(octants)) == 8


def test_icosphere_surface_and_interior(tmp_path):
    radius = 1.7
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    path = tmp_path / "ball.ply"
    sphere.export(path)
    g = mesh_to_gaussians(path, NUM, seed=1, size=SIZE)

    # Independent geometry of the polyhedron: vertices at `radius`, faces at least r_in from 0.
    vertices, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    factor = SIZE / (vertices.max(axis=0) - vertices.min(axis=0)).max()
    center = (vertices.max(axis=0) + vertices.min(axis=0)) / 2
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    normals = np.cross(b - a, c - a)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    r_in = np.abs((normals * (a - center)).sum(axis=1)).min() * factor
    r_out = radius * factor

    surface, interior = _split(g)
    surface_radius = surface.norm(dim=-1)
    assert (surface_radius >= r_in - 1e-6).all() and (surface_radius <= r_out + 1e-6).all()
    assert (interior.norm(dim=-1) < r_in).all()
    assert interior.norm(dim=-1).max().item() > 0.7 * r_in  # fills the ball, not just its core


def test_vertex_colours_are_interpolated(tmp_path):
    box = trimesh.creation.box(extents=BOX_EXTENTS)
    box.apply_translation(BOX_CENTER)

    def linear_color(points):  # an affine colour field, exact under barycentric interpolation
        unit = (points - (BOX_CENTER - BOX_EXTENTS / 2)) / BOX_EXTENTS
        return 0.15 + 0.7 * unit[:, [0, 1, 2]] * np.array([1.0, 0.5, 1.0]) + [0, 0.2, 0]

    rgb = np.round(linear_color(box.vertices) * 255).astype(np.uint8)
    box.visual = trimesh.visual.ColorVisuals(
        box, vertex_colors=np.column_stack([rgb, np.full(len(rgb), 255)])
    )
    path = tmp_path / "colored.ply"
    box.export(path)

    g = mesh_to_gaussians(path, NUM, seed=2, size=SIZE)  # texture="auto": mesh colours
    surface, _ = _split(g)
    factor = SIZE / BOX_EXTENTS.max()
    original_positions = surface.numpy() / factor + BOX_CENTER
    expected = linear_color(original_positions)
    np.testing.assert_allclose(g.colors[: len(surface)].numpy(), expected, atol=1.5 / 255)
    # Interior Gaussians take the colour of a surface sample.
    surface_colors = {tuple(c) for c in g.colors[: len(surface)].numpy().round(5)}
    assert all(tuple(c) in surface_colors for c in g.colors[len(surface) :].numpy().round(5))

    checker = mesh_to_gaussians(path, NUM, seed=2, size=SIZE, texture="checker")
    assert len(torch.unique((checker.colors * 255).round(), dim=0)) == 3


@pytest.mark.parametrize("suffix", [".obj", ".glb"])
def test_uv_texture_and_open_mesh_fallback(tmp_path, suffix):
    """A textured open quad: colours follow the image; no interior exists, so all on the surface."""
    image = np.zeros((64, 64, 3), dtype=np.uint8)
    image[:, :32] = (220, 40, 30)  # left half red
    image[:, 32:] = (30, 40, 220)  # right half blue
    vertices = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=float)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    uv = (vertices[:, :2] + 1) / 2
    if suffix == ".obj":  # OBJ + MTL + PNG
        material = trimesh.visual.material.SimpleMaterial(image=Image.fromarray(image))
    else:  # glTF PBR material, no base colour factor
        material = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray(image))
    visual = trimesh.visual.TextureVisuals(uv=uv, material=material)
    quad = trimesh.Trimesh(vertices, faces, visual=visual, process=False)
    path = tmp_path / f"quad{suffix}"
    quad.export(path)

    g = mesh_to_gaussians(path, 500, seed=0, size=SIZE)
    assert g.num_gaussians == 500
    assert (g.means[:, 2].abs() < 1e-6).all()  # no interior samples for an open surface
    colors, x = g.colors.numpy(), g.means[:, 0].numpy()
    red, blue = np.array([220, 40, 30]) / 255, np.array([30, 40, 220]) / 255
    assert (x < -0.02).sum() > 100 and (x > 0.02).sum() > 100
    assert np.abs(colors[x < -0.02] - red).max() < 0.02
    assert np.abs(colors[x > 0.02] - blue).max() < 0.02


def test_plain_mesh_gets_procedural_colours_above_background(tmp_path):
    g = mesh_to_gaussians(_box_file(tmp_path), NUM, seed=0)
    assert len(torch.unique((g.colors * 255).round(), dim=0)) == 3  # "auto" → checker
    assert (g.colors > 0.0392 + 0.02).all()
    with pytest.raises(InputError, match="texture"):
        mesh_to_gaussians(_box_file(tmp_path), NUM, texture="mesh")
    with pytest.raises(InputError, match="auto, mesh, checker"):
        mesh_to_gaussians(_box_file(tmp_path), NUM, texture="marble")


def test_deterministic_given_seed(tmp_path):
    path = _box_file(tmp_path)
    a, b = mesh_to_gaussians(path, 500, seed=4), mesh_to_gaussians(path, 500, seed=4)
    c = mesh_to_gaussians(path, 500, seed=5)
    assert torch.equal(a.means, b.means) and torch.equal(a.sh0, b.sh0)
    assert torch.equal(a.log_scales, b.log_scales)
    assert not torch.allclose(a.means, c.means)


def test_accepts_an_in_memory_mesh_and_leaves_it_unchanged():
    box = trimesh.creation.box(extents=BOX_EXTENTS)
    before = box.vertices.copy()
    g = mesh_to_gaussians(box, 300, seed=0, size=0.8)
    assert np.array_equal(box.vertices, before)
    assert (g.means.amax(0) - g.means.amin(0)).max().item() == pytest.approx(0.8, rel=1e-5)


@pytest.mark.parametrize(
    "name, content",
    [
        ("broken.glb", b"glTF\x02\x00\x00\x00garbage that is not a binary gltf"),
        ("broken.stl", b"\x00\x01\x02 definitely not an stl"),
        ("empty.obj", b"# nothing but a comment\n"),
        ("broken.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n"),
    ],
)
def test_corrupt_file_raises_input_error_naming_it(tmp_path, name, content):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(InputError) as info:
        mesh_to_gaussians(path, 100)
    assert name in str(info.value) and "\n" not in str(info.value)


def test_missing_file_raises_input_error(tmp_path):
    with pytest.raises(InputError, match=r"nowhere\.obj"):
        load_mesh(tmp_path / "nowhere.obj")


def test_pybullet_mesh_paths():
    if importlib.util.find_spec("pybullet_data") is None:
        with pytest.raises(InputError, match=r"pip install reconphys\[meshes\]"):
            pybullet_mesh_paths()
    else:
        paths = pybullet_mesh_paths()
        assert len(paths) > 100 and all(p.suffix == ".obj" and p.is_file() for p in paths)


@pytest.mark.parametrize(
    "bad, field",
    [
        ({"num_gaussians": 15}, "num_gaussians"),
        ({"num_gaussians": 100.5}, "num_gaussians"),
        ({"size": 0.0}, "size"),
        ({"size": float("nan")}, "size"),
        ({"interior_fraction": -0.1}, "interior_fraction"),
    ],
)
def test_meshes_and_procedural_shapes_check_the_same_arguments(bad, field):
    from reconphys.assets.procedural import make_procedural_gaussians

    arguments = {"num_gaussians": 100, "size": SIZE, "interior_fraction": 0.3, **bad}
    for sample in (
        lambda: mesh_to_gaussians(trimesh.creation.box(BOX_EXTENTS), **arguments),
        lambda: make_procedural_gaussians("sphere", **arguments),
    ):
        with pytest.raises(InputError) as info:
            sample()
        assert info.value.field == field
