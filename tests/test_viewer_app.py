"""The viser UI without a browser: camera and splat conversions, and the UI callbacks."""

from __future__ import annotations

import socket
import time
from types import SimpleNamespace

import pytest
import torch
from test_viewer_session import make_small_asset

from reconphys.assets.gaussians import Gaussians
from reconphys.geometry import matrix_to_quaternion
from reconphys.render import dataset_views
from reconphys.viewer import ViewerSession
from reconphys.viewer.app import camera_from_viser, splat_arrays


def test_camera_from_viser_matches_the_dataset_view():
    view = dataset_views(64, 48)  # 40° vertical field of view
    world_to_cam = view.world_to_cam[1].double()
    cam_to_world = torch.linalg.inv(world_to_cam)
    wxyz = matrix_to_quaternion(cam_to_world[:3, :3]).tolist()
    camera = camera_from_viser(
        cam_to_world[:3, 3].tolist(), wxyz, fov=torch.pi * 40 / 180, aspect=64 / 48, height=48
    )
    assert (camera.width, camera.height) == (64, 48)
    assert torch.allclose(camera.world_to_cam[0], view.world_to_cam[1], atol=1e-5)
    assert torch.allclose(camera.K[0], view.K[1], atol=1e-4)


def test_splat_covariances_are_rotated_scales():
    quarter_turn_z = torch.tensor([[0.5**0.5, 0.0, 0.0, 0.5**0.5]])
    gaussians = Gaussians.from_activated(
        means=torch.zeros(1, 3),
        scales=torch.tensor([[0.1, 0.02, 0.03]]),
        opacities=torch.tensor([0.5]),
        colors=torch.tensor([[1.0, 0.5, 0.0]]),
        quats=quarter_turn_z,
    )
    arrays = splat_arrays(gaussians)
    expected = torch.diag(torch.tensor([0.02**2, 0.1**2, 0.03**2]))  # x and y swap
    assert torch.allclose(torch.from_numpy(arrays["covariances"][0]), expected, atol=1e-7)
    assert arrays["opacities"].shape == (1, 1) and arrays["rgbs"].shape == (1, 3)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_ui_callbacks_drive_the_session(tmp_path):
    pytest.importorskip("viser", reason="the viewer extra is not installed: pip install viser")
    from reconphys.viewer.app import ViewerApp, status_markdown

    session = ViewerSession(make_small_asset(num_gaussians=400, num_anchors=64))
    with ViewerApp(session, port=_free_port(), record_dir=tmp_path / "rec") as app:
        app.start()
        app._toggle_play()
        assert session.playing and app._play.label == "Pause"
        app._toggle_play()
        assert not session.playing

        # A click without Grab armed does nothing; armed, a ray from above grabs the top.
        means = session.gaussian_means()
        top = means[int(torch.argmax(means[:, 2]))]
        click = SimpleNamespace(
            ray_origin=(top + torch.tensor([0.0, 0.0, 1.0])).tolist(),
            ray_direction=[0.0, 0.0, -1.0],
            modifier=None,
        )
        app._on_click(click)
        assert session.grips() == {}
        app._arm()
        app._on_click(click)
        assert list(session.grips()) == ["grip 1"]
        # (The grip point is the hit Gaussian's centre at click time; a frame that was still
        # running when play was toggled off may have moved it slightly since ``top`` was read.)
        placed = session.grips()["grip 1"]["goal"]
        assert float((placed - top).norm()) < 0.02
        app._nudge((0.0, 0.0, 1.0))  # key O: up by the key step (2 cm)
        goal = session.grips()["grip 1"]["goal"]
        assert (goal - placed).tolist() == pytest.approx([0.0, 0.0, 0.02], abs=1e-6)
        app.refresh()
        assert "grip 1" in app._grip_nodes

        app._toggle_record(SimpleNamespace(client=None))
        session.request_step(3)
        deadline = time.perf_counter() + 30
        while session.status().frame < 3 and time.perf_counter() < deadline:
            time.sleep(0.02)
        app._record_view.value = "dataset view 0"
        app._record_height.value = 64
        app._toggle_record(SimpleNamespace(client=None))
        deadline = time.perf_counter() + 60
        while not list(tmp_path.glob("rec/*/interaction.mp4")) and time.perf_counter() < deadline:
            time.sleep(0.1)
        assert list(tmp_path.glob("rec/*/interaction.mp4")), app._record_status.content

        app._release("grip 1")
        app.refresh()
        assert session.grips() == {} and app._grip_nodes == {}
        assert f"frame {session.status().frame} ·" in status_markdown(session)
