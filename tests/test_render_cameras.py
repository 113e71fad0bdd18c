"""Cameras: intrinsics, look-at and the dataset views, checked against plain geometry."""

import math

import pytest
import torch

from reconphys.render import Cameras, dataset_views, intrinsics_from_fov, look_at


def project(
    world_to_cam: torch.Tensor,  # [4, 4]
    K: torch.Tensor,  # [3, 3]
    point: torch.Tensor,  # [3] world
) -> tuple[torch.Tensor, torch.Tensor]:  # [2] pixels, [] camera depth
    cam = world_to_cam[:3, :3] @ point + world_to_cam[:3, 3]
    uvw = K @ cam
    return uvw[:2] / uvw[2], cam[2]


def test_intrinsics_vertical_fov_square_pixels_centred():
    K = intrinsics_from_fov(40.0, width=80, height=60, dtype=torch.float64)
    assert K[0, 0] == K[1, 1]
    assert K[0, 2] == 40.0 and K[1, 2] == 30.0
    # A ray at half the vertical field of view above the axis hits the top edge (v = 0).
    half = math.radians(20.0)
    v = K[1, 1] * (-math.tan(half)) + K[1, 2]
    assert abs(v) < 1e-9
    assert K.dtype == torch.float64
    with pytest.raises(ValueError, match="fov_deg"):
        intrinsics_from_fov(180.0, 8, 8)


def test_look_at_is_rigid_and_maps_eye_and_target():
    eye = torch.tensor([[1.0, -2.0, 0.7], [0.3, 0.4, 2.0], [-1.5, 0.2, 0.1]], dtype=torch.float64)
    target = torch.tensor([[0.0, 0.0, 0.3], [0.1, -0.2, 0.0], [0.5, 0.5, 0.5]], dtype=torch.float64)
    world_to_cam = look_at(eye, target)
    assert world_to_cam.shape == (3, 4, 4)
    rotation = world_to_cam[:, :3, :3]
    eye3 = torch.eye(3, dtype=torch.float64).expand(3, 3, 3)
    torch.testing.assert_close(rotation @ rotation.transpose(-1, -2), eye3)
    torch.testing.assert_close(torch.linalg.det(rotation), torch.ones(3, dtype=torch.float64))
    torch.testing.assert_close(
        world_to_cam[:, 3], torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64).expand(3, 4)
    )

    def apply(points):
        return (rotation @ points.unsqueeze(-1)).squeeze(-1) + world_to_cam[:, :3, 3]

    torch.testing.assert_close(apply(eye), torch.zeros(3, 3, dtype=torch.float64))
    distance = (target - eye).norm(dim=-1)
    expected = torch.stack([torch.zeros(3), torch.zeros(3), distance.float()], dim=-1)
    torch.testing.assert_close(apply(target), expected.double())


def test_look_at_opencv_axes():
    # Camera on the +x axis looking at the origin, world z up: world up must appear as image up
    # (−y in OpenCV) and world +y on the image's right (+x), since we face −x.
    world_to_cam = look_at(torch.tensor([3.0, 0.0, 0.0]), torch.zeros(3))
    R = world_to_cam[:3, :3]
    torch.testing.assert_close(R @ torch.tensor([0.0, 0.0, 1.0]), torch.tensor([0.0, -1.0, 0.0]))
    torch.testing.assert_close(R @ torch.tensor([0.0, 1.0, 0.0]), torch.tensor([1.0, 0.0, 0.0]))
    torch.testing.assert_close(R @ torch.tensor([-1.0, 0.0, 0.0]), torch.tensor([0.0, 0.0, 1.0]))


def test_look_at_rejects_degenerate_input():
    with pytest.raises(ValueError, match="parallel"):
        look_at(torch.tensor([0.0, 0.0, 2.0]), torch.zeros(3))
    with pytest.raises(ValueError, match="differ"):
        look_at(torch.ones(3), torch.ones(3))


def test_dataset_views_geometry():
    width, height, radius, elevation = 64, 48, 2.0, 15.0
    target = torch.tensor([0.0, 0.0, 0.3], dtype=torch.float64)
    cams = dataset_views(width, height, radius=radius, elevation_deg=elevation, dtype=torch.float64)
    assert cams.num_cameras == 4 and cams.K.shape == (4, 3, 3)
    assert cams.world_to_cam.shape == (4, 4, 4) and cams.batch_shape == ()

    el = math.radians(elevation)
    horizontal, up = radius * math.cos(el), radius * math.sin(el)
    expected_centres = torch.tensor(
        [
            [horizontal, 0.0, up],
            [0.0, horizontal, up],
            [-horizontal, 0.0, up],
            [0.0, -horizontal, up],
        ],
        dtype=torch.float64,
    )
    torch.testing.assert_close(cams.centers, expected_centres + target)

    for c in range(4):
        uv, depth = project(cams.world_to_cam[c], cams.K[c], target)
        torch.testing.assert_close(uv, torch.tensor([width / 2, height / 2], dtype=torch.float64))
        assert depth == pytest.approx(radius)
        # The contact point below the target is visible and below the image centre.
        uv_ground, _ = project(cams.world_to_cam[c], cams.K[c], torch.zeros(3, dtype=torch.float64))
        assert height / 2 < uv_ground[1] < height and 0 <= uv_ground[0] <= width


def test_cam_to_world_inverts_world_to_cam():
    cams = dataset_views(32, 32, dtype=torch.float64)
    identity = torch.eye(4, dtype=torch.float64).expand(4, 4, 4)
    torch.testing.assert_close(cams.cam_to_world @ cams.world_to_cam, identity)


def test_cameras_to_expand_and_validation():
    cams = dataset_views(32, 16)
    assert cams.K.dtype == torch.float32
    cams64 = cams.to(torch.float64)
    assert cams64.K.dtype == torch.float64 and cams64.width == 32 and cams64.height == 16
    batched = cams.expand((2,))
    assert batched.K.shape == (2, 4, 3, 3) and batched.batch_shape == (2,)
    with pytest.raises(ValueError, match="same leading dims"):
        Cameras(K=cams.K[:2], world_to_cam=cams.world_to_cam, width=32, height=16)
    with pytest.raises(ValueError, match="positive"):
        Cameras(K=cams.K, world_to_cam=cams.world_to_cam, width=0, height=16)


def test_select_picks_cameras_by_index_or_slice():
    cameras = dataset_views(32, 24)
    picked = cameras.select([2, 0])
    assert torch.equal(picked.K, cameras.K[[2, 0]]) and (picked.width, picked.height) == (32, 24)
    assert torch.equal(picked.world_to_cam, cameras.world_to_cam[[2, 0]])
    assert torch.equal(cameras.select(slice(1, 2)).K, cameras.K[1:2])
    batched = Cameras(
        cameras.K.expand(5, -1, -1, -1), cameras.world_to_cam.expand(5, -1, -1, -1), 32, 24
    )
    assert batched.select(torch.tensor([3])).K.shape == (5, 1, 3, 3)
