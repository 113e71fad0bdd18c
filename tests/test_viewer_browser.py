"""Acceptance test of the browser viewer: viser server + headless Chromium (issue 9).

Needs the optional packages viser and selenium (pip) and the Debian packages chromium and
chromium-driver. When the browser is missing, the test installs it with apt-get if it runs as root
(set RECONPHYS_NO_APT=1 to forbid that); otherwise, or when any piece is missing, it is skipped
with the reason. Set RECONPHYS_VIEWER_SCREENSHOTS=DIR to keep the screenshots.
"""

from __future__ import annotations

import io
import os
import shutil
import socket
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from test_viewer_session import make_small_asset

from reconphys.viewer import ViewerSession

pytest.importorskip("viser", reason="the viewer extra is not installed: pip install viser")
pytest.importorskip("selenium", reason="selenium is not installed: pip install selenium")

BROWSERS = ("chromium", "chromium-browser", "google-chrome")
PACKAGES = ("chromium", "chromium-driver")


def _find_chromium() -> tuple[str | None, str | None]:
    browser = next((path for name in BROWSERS if (path := shutil.which(name))), None)
    return browser, shutil.which("chromedriver")


def _install_chromium() -> str:
    """Try ``apt-get install chromium chromium-driver``; returns what happened."""
    if os.environ.get("RECONPHYS_NO_APT"):
        return "RECONPHYS_NO_APT is set, so apt-get was not tried"
    if shutil.which("apt-get") is None:
        return "no apt-get on this machine"
    if os.geteuid() != 0:
        return "not root, so apt-get was not tried (sudo apt-get install chromium chromium-driver)"
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    install = ["apt-get", "install", "-y", "--no-install-recommends", *PACKAGES]
    for commands in ([install], [["apt-get", "update"], install]):
        try:
            for command in commands:
                subprocess.run(command, env=env, check=True, capture_output=True, timeout=900)
            return "installed with apt-get"
        except (subprocess.SubprocessError, OSError) as e:
            failure = f"apt-get failed: {e}"
    return failure


@pytest.fixture(scope="module")
def chrome():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    browser, driver = _find_chromium()
    if browser is None or driver is None:
        what = _install_chromium()
        browser, driver = _find_chromium()
        if browser is None or driver is None:
            pytest.skip(f"headless Chromium and chromedriver are not available ({what})")
    options = webdriver.ChromeOptions()
    options.binary_location = browser
    for argument in (
        "--headless=new",
        "--no-sandbox",
        "--disable-dev-shm-usage",
        "--window-size=1000,700",
        # No GPU here: WebGL through SwiftShader, which Chromium allows only when asked.
        "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader",
        "--ignore-gpu-blocklist",
    ):
        options.add_argument(argument)
    session = webdriver.Chrome(service=Service(driver), options=options)
    yield session
    session.quit()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _screenshot(chrome, name: str, folder: Path) -> np.ndarray:  # [H, W, 3] uint8
    import imageio.v3 as iio

    png = chrome.get_screenshot_as_png()
    (folder / f"{name}.png").write_bytes(png)
    keep = os.environ.get("RECONPHYS_VIEWER_SCREENSHOTS")
    if keep:
        Path(keep).mkdir(parents=True, exist_ok=True)
        (Path(keep) / f"{name}.png").write_bytes(png)
    return iio.imread(io.BytesIO(png))[..., :3].astype(np.int16)


def _changed_pixels(a: np.ndarray, b: np.ndarray) -> int:
    return int((np.abs(a - b).max(-1) > 40).sum())


def _wait(condition, seconds: float) -> bool:
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline:
        if condition():
            return True
        time.sleep(0.1)
    return condition()


def test_browser_shows_the_object_and_a_grab_moves_it(chrome, tmp_path):
    from reconphys.viewer.app import ViewerApp

    asset = make_small_asset(num_gaussians=3000, num_anchors=128, height=0.02)
    session = ViewerSession(asset)
    with ViewerApp(session, port=_free_port()) as app:
        app.start()
        chrome.get(app.url)
        assert _wait(lambda: len(app.server.get_clients()) > 0, 30), "the page never connected"
        # The browser sorts and draws the splats after the scene arrives; wait until two
        # screenshots a second apart agree.
        previous = _screenshot(chrome, "start", tmp_path)
        for _ in range(20):
            time.sleep(1.0)
            shown = _screenshot(chrome, "viewer_object", tmp_path)
            if _changed_pixels(shown, previous) == 0:
                break
            previous = shown
        app._splats.visible = False
        time.sleep(1.5)
        hidden = _screenshot(chrome, "viewer_hidden", tmp_path)
        app._splats.visible = True
        object_pixels = _changed_pixels(shown, hidden)
        assert object_pixels > 3000, f"only {object_pixels} pixels show the object"

        # Grab the top through the controller API and lift it 0.15 m while the simulation plays.
        means = session.gaussian_means()
        top = means[int(torch.argmax(means[:, 2]))]
        name = app.grab(top)
        held = session.grips()[name]["anchors"]
        before = session.anchor_positions()[held].mean(0)
        session.move_grip(name, top + torch.tensor([0.0, 0.0, 0.15]))
        session.play()
        assert _wait(lambda: session.status().frame >= 20, 60), "the simulation did not run"
        session.pause()
        after = session.anchor_positions()[held].mean(0)
        status = session.status()
        assert float(after[2] - before[2]) == pytest.approx(0.15, abs=0.03)
        assert torch.isfinite(session.state().x).all() and torch.isfinite(session.state().v).all()
        assert status.max_speed < 3.0 and status.lowest_z > -1e-4
        # ... and the browser shows the lifted object.
        time.sleep(2.0)
        lifted = _screenshot(chrome, "viewer_grab", tmp_path)
        assert _changed_pixels(lifted, shown) > 1000
