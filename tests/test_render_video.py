"""``tile_images`` and the four image grids drawn with it: each must write the same bytes as the
grid code it replaced (written out inline here as the reference)."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from PIL import Image, ImageDraw

from reconphys.data import show
from reconphys.eval import plots
from reconphys.pipeline import preview
from reconphys.render.video import tile_images, to_uint8, write_image, write_strip


def _frames(seed: int, count: int, height: int, width: int) -> np.ndarray:  # [T, H, W, 3] uint8
    return np.random.default_rng(seed).integers(0, 256, (count, height, width, 3), dtype=np.uint8)


def test_tile_images_layout():
    a, b = _frames(0, 2, 2, 3)
    grid = tile_images([[a, None], [b, a]], scale=2, pad=(1, 0, 0, 2), fill=7, blank=(1, 2, 3))
    assert grid.shape == (2 * (1 + 4), 2 * (6 + 2), 3)
    np.testing.assert_array_equal(grid[1:5, 0:6], a.repeat(2, 0).repeat(2, 1))
    np.testing.assert_array_equal(grid[1:5, 8:14], np.broadcast_to([1, 2, 3], (4, 6, 3)))
    np.testing.assert_array_equal(grid[6:10, 8:14], a.repeat(2, 0).repeat(2, 1))
    assert (grid[0] == 7).all() and (grid[:, 6:8] == 7).all() and (grid[:, 14:] == 7).all()


def test_write_strip_matches_the_concatenation(tmp_path):
    frames = _frames(1, 9, 5, 7)
    picks = np.linspace(0, len(frames) - 1, 6).round().astype(int)
    old = write_image(tmp_path / "old.png", np.concatenate(list(frames[picks]), axis=1))
    new = write_strip(tmp_path / "new.png", frames)
    assert new.read_bytes() == old.read_bytes()


def _old_preview_sheet(observed, simulated, count=6):
    num_frames, height, width = simulated.shape[:3]
    picks = np.linspace(0, num_frames - 1, min(count, num_frames)).round().astype(int)
    factor = max(1, math.ceil(preview.PREVIEW_MIN_SIZE / 2 / max(height, width)))
    top = torch.zeros(len(picks), height, width, 3)
    for column, t in enumerate(picks):
        if t < observed.shape[0]:
            top[column] = observed[t]
    top, bottom = preview._enlarge(top, factor), preview._enlarge(simulated[picks], factor)
    rows = []
    for images in (top, bottom):
        bar = torch.full((len(picks), images.shape[1], preview.SEPARATOR, 3), 0.5)
        rows.append(torch.cat([images, bar], dim=2).permute(1, 0, 2, 3).flatten(1, 2))
    sheet = torch.cat([rows[0], torch.full((preview.SEPARATOR, rows[0].shape[1], 3), 0.5), rows[1]])
    return to_uint8(sheet)


@pytest.mark.parametrize("size", [(4, 5), (3, 3)])  # enlarged 26 and 43 times
def test_preview_contact_sheet_unchanged(size):
    generator = torch.Generator().manual_seed(2)
    observed = torch.rand(4, *size, 3, generator=generator)
    simulated = torch.rand(11, *size, 3, generator=generator)
    np.testing.assert_array_equal(
        preview.contact_sheet(observed, simulated), _old_preview_sheet(observed, simulated)
    )


def test_data_show_contact_sheet_unchanged(monkeypatch):
    stored = {f"s{i}.npz": {"view_0": _frames(i, 7, 20, 20)} for i in range(5)}
    samples = [{"frames": name} for name in stored]
    monkeypatch.setattr(show, "read_manifest", lambda root: {"samples": samples})
    monkeypatch.setattr(show, "read_npz", lambda path, keys: stored[Path(path).name])
    rows = []
    for i in np.unique(np.linspace(0, 4, 4).round()).astype(int):
        frames = stored[f"s{i}.npz"]["view_0"]
        tiles = frames[np.linspace(0, 6, 7).round().astype(int)]
        factor = max(1, -(-show.SHEET_TILE // tiles.shape[1]))
        tiles = tiles.repeat(factor, 1).repeat(factor, 2)
        tiles = np.pad(tiles, ((0, 0), (1, 1), (1, 1), (0, 0)), constant_values=60)
        rows.append(np.concatenate(list(tiles), axis=1))
    np.testing.assert_array_equal(show.contact_sheet(Path("unused")), np.concatenate(rows, axis=0))


def _old_eval_sheet(results, path):
    names = plots._rows_with_data(results)
    columns = plots.sheet_columns(results.num_frames)
    samples = list(results.ground_truth_sheets)
    height, width = next(iter(results.ground_truth_sheets.values())).shape[1:3]
    tile_h, tile_w = height * plots.SHEET_SCALE, width * plots.SHEET_SCALE
    label_w, header = 180, 24
    rows = [(s, name) for s in samples for name in [None, *names]]
    image = Image.new(
        "RGB",
        (label_w + len(columns) * (tile_w + 2), header + len(rows) * (tile_h + 2)),
        plots.WHITE,
    )
    draw = ImageDraw.Draw(image)
    font = plots._font(12)
    for c, frame in enumerate(columns):
        x = label_w + c * (tile_w + 2) + tile_w // 2
        draw.text((x, 4), f"frame {frame}", fill=plots.BLACK, font=font, anchor="mt")
    for r, (sample, name) in enumerate(rows):
        y = header + r * (tile_h + 2)
        if name is None:
            frames, label = results.ground_truth_sheets[sample], f"{sample}\nground truth"
        else:
            found = [x for x in results.results if x.row == name and x.sample == sample]
            frames = found[0].sheet if found else None
            label = name
        draw.multiline_text((6, y + tile_h // 2), label, fill=plots.BLACK, font=font, anchor="lm")
        for c, frame in enumerate(columns):
            x = label_w + c * (tile_w + 2)
            if frames is None or frame >= len(frames):
                draw.rectangle([x, y, x + tile_w - 1, y + tile_h - 1], fill=(60, 60, 60))
                draw.text(
                    (x + tile_w // 2, y + tile_h // 2),
                    "n/a",
                    fill=plots.WHITE,
                    font=font,
                    anchor="mm",
                )
                continue
            tile = Image.fromarray(frames[frame]).resize((tile_w, tile_h), Image.NEAREST)
            image.paste(tile, (x, y))
    image.save(path)


def test_eval_contact_sheet_unchanged(tmp_path):
    results = SimpleNamespace(
        rows=[SimpleNamespace(name=n) for n in ("reconphys", "static", "absent")],
        results=[
            SimpleNamespace(row="reconphys", sample="a", sheet=_frames(3, 30, 6, 8)),
            SimpleNamespace(row="reconphys", sample="b", sheet=None),
            SimpleNamespace(row="static", sample="a", sheet=_frames(4, 12, 6, 8)),
        ],
        num_frames=30,
        ground_truth_sheets={"a": _frames(5, 30, 6, 8), "b": _frames(6, 30, 6, 8)},
    )
    plots.contact_sheet(results, tmp_path / "new.png")
    _old_eval_sheet(results, tmp_path / "old.png")
    assert (tmp_path / "new.png").read_bytes() == (tmp_path / "old.png").read_bytes()


def test_the_preview_outlines_the_masks_on_the_unmasked_recording():
    """The preview's recording panel is the frames as filmed with the masks' outline in green:
    the ring of a square mask, nothing inside it or outside it changed."""
    frames = torch.rand(2, 12, 12, 3) * 0.5  # a floor and a backdrop: never pure green
    masks = torch.zeros(2, 12, 12)
    masks[:, 3:9, 4:10] = 1.0
    shown = preview.outlined(frames, masks)
    green = (shown == torch.tensor(preview.OUTLINE)).all(-1)  # [2, 12, 12]
    ring = masks.bool().clone()
    ring[:, 4:8, 5:9] = False  # the square less its interior: its border pixels
    assert torch.equal(green, ring)
    assert torch.equal(shown[~green], frames[~green])


def _falling_square(count: int, size: int) -> torch.Tensor:  # [T, H, W] a square falling down
    masks = torch.zeros(count, size, size)
    for t in range(count):
        top = round(2 + (size - 12) * t / (count - 1))
        masks[t, top : top + 6, 10:16] = 1.0
    return masks


def test_the_background_plate_is_the_scene_without_the_object():
    """Each pixel the object leaves free in some frame reads the background exactly — also where
    something else (a hand) covers it in a minority of those frames (a median, not a mean); a
    pixel covered in every frame takes a free pixel's value; no free pixel: black."""
    count, size = 20, 32
    background = torch.rand(size, size, 3, generator=torch.Generator().manual_seed(3))
    masks = _falling_square(count, size)
    masks[:, 24:30, 2:8] = 1.0  # something that never moves: never free
    frames = background.expand(count, -1, -1, -1).clone()
    frames[masks.bool()] = torch.tensor([1.0, 0.0, 0.0])  # the object, red
    frames[:3, 0:4, 20:30] = torch.tensor([0.9, 0.8, 0.7])  # a hand, in 3 frames, not in the masks
    plate = preview.background_plate(frames, masks)
    margin = max(1, round(preview.PLATE_MARGIN * size))
    widened = torch.nn.functional.max_pool2d(masks[:, None], 2 * margin + 1, 1, margin)[:, 0]
    free = (widened < 0.5).any(0)  # [H, W] free in some frame
    picks = np.unique(np.linspace(0, count - 1, preview.PLATE_FRAMES).round().astype(int))
    free_in_picks = (widened[picks] < 0.5).any(0)
    assert free_in_picks.float().mean() > 0.5 and not free_in_picks[27, 5]
    assert torch.equal(plate[free_in_picks], background[free_in_picks])
    assert torch.equal(plate[0:4, 20:30], background[0:4, 20:30])  # the hand left out
    values = {tuple(v) for v in background[free].tolist()}
    assert all(tuple(v) in values for v in plate[~free_in_picks].tolist())
    covered = torch.ones(count, size, size)
    assert torch.equal(preview.background_plate(frames, covered), torch.zeros(size, size, 3))


def test_the_simulated_panel_is_laid_over_the_plate():
    """``rgb + (1 − alpha)·plate`` for colour premultiplied on black (render_sequence's)."""
    plate = torch.tensor([0.2, 0.4, 0.6]).expand(2, 3, 3)
    rendered = torch.zeros(1, 2, 3, 4)
    rendered[0, 0, 0] = torch.tensor([0.5, 0.5, 0.5, 1.0])  # opaque grey
    rendered[0, 0, 1] = torch.tensor([0.25, 0.0, 0.0, 0.5])  # half-covered red
    laid = preview.over_plate(rendered, plate)[0]
    assert torch.allclose(laid[0, 0], torch.tensor([0.5, 0.5, 0.5]))
    assert torch.allclose(laid[0, 1], torch.tensor([0.35, 0.2, 0.3]))
    assert torch.equal(laid[1], plate[1])  # nothing rendered there


def test_render_sequence_gives_the_opacity_beside_the_colour():
    from reconphys.assets.gaussians import Gaussians
    from reconphys.render import dataset_views, render
    from reconphys.render.sequence import render_sequence

    generator = torch.Generator().manual_seed(5)
    n = 40
    gaussians = Gaussians(
        means=(torch.rand(n, 3, generator=generator) - 0.5) * 0.4,
        quats=torch.randn(n, 4, generator=generator),
        log_scales=torch.full((n, 3), math.log(0.03)),
        opacity_logits=torch.randn(n, generator=generator),
        sh0=torch.randn(n, 3, generator=generator),
    )
    camera = dataset_views(24, 24, azimuths_deg=(0.0,))
    means = gaussians.means[None] + torch.tensor([[[0.0, 0.0, 0.3]], [[0.0, 0.0, 0.2]]])
    rgba = render_sequence(gaussians, means, camera, "torch", with_alpha=True)
    assert rgba.shape == (2, 24, 24, 4)
    assert torch.equal(rgba[..., :3], render_sequence(gaussians, means, camera, "torch"))
    alpha = render(gaussians.with_means(means[1]), camera, "torch").alpha[0]
    assert torch.equal(rgba[1, ..., 3], alpha) and alpha.max() > 0.5 and alpha.min() < 0.01


def test_a_recordings_unmasked_frames_are_kept_beside_the_masked_ones(tmp_path):
    """``Observation.unmasked`` is what was filmed (background included); ``frames`` are those
    times the masks, as the models read them."""
    from reconphys.capture.observation import stored_observation

    frames = torch.rand(4, 16, 16, 3)
    masks = torch.zeros(4, 16, 16)
    for t in range(4):
        masks[t, 2 + 2 * t : 7 + 2 * t, 5:10] = 1.0  # a falling square
    observation = stored_observation(frames, torch.eye(3) * 16, torch.eye(4), 0.03, "test",
                                     masks=masks, mask_source="given")  # fmt: skip
    assert torch.equal(observation.unmasked, frames)
    assert torch.equal(observation.frames, frames * masks[..., None])


def test_a_wide_sheets_caption_is_enlarged():
    """The caption's text grows by a whole factor with the sheet's width (its strip is the small
    sheet's, each pixel repeated), and a narrow sheet's is as it was."""
    lines = ["log k/m 3.00  [2.00, 4.00] (10-90 %)"]
    narrow = preview.with_caption(np.zeros((5, 700, 3), np.uint8), lines)
    wide = preview.with_caption(np.zeros((5, 2100, 3), np.uint8), lines)
    factor = 2100 // preview.CAPTION_WIDTH
    assert narrow.shape == (5 + 16, 700, 3) and wide.shape == (5 + 16 * factor, 2100, 3)
    strip = narrow[5:]
    assert strip.any() and strip[:, 400:].max() == 0  # text on the left
    small = wide[5::factor, ::factor][:, :700]
    np.testing.assert_array_equal(small, strip)


def test_a_large_recording_is_previewed_smaller():
    """Above PREVIEW_MAX_SIDE the preview's frames are area-averaged, its masks kept where they
    cover half a pixel and K scaled with them (the object's pixel stays the object's); a small
    recording is shown as it is."""
    from reconphys.capture.observation import stored_observation

    count, height, width = 3, 2 * preview.PREVIEW_MAX_SIDE, 3 * preview.PREVIEW_MAX_SIDE // 2
    frames = torch.rand(count, height, width, 3, generator=torch.Generator().manual_seed(7))
    masks = torch.zeros(count, height, width)
    for t in range(count):  # a falling square on 2 × 2-pixel cells: whole pixels at half the size
        masks[t, 100 + 20 * t : 140 + 20 * t, 60:100] = 1.0
    K = torch.tensor([[500.0, 0.0, width / 2], [0.0, 500.0, height / 2], [0.0, 0.0, 1.0]])
    observation = stored_observation(frames, K, torch.eye(4), 0.03, "test", masks=masks,
                                     mask_source="given")  # fmt: skip
    shown, shown_masks, camera = preview.preview_view(observation)
    assert shown.shape == (count, height // 2, width // 2, 3)
    assert (camera.width, camera.height) == (width // 2, height // 2)
    pooled = frames.reshape(count, height // 2, 2, width // 2, 2, 3).mean((2, 4))
    assert torch.allclose(shown, pooled, atol=1e-6)
    assert torch.equal(shown_masks, masks[:, ::2, ::2])
    assert torch.allclose(camera.K[:2].float(), K[:2] / 2)
    cut = np.s_[:, 90:190, 50:110]  # 100 × 60 px about the square
    small = stored_observation(frames[cut], K, torch.eye(4), 0.03, "test", masks=masks[cut],
                               mask_source="given")  # fmt: skip
    kept = preview.preview_view(small)
    assert torch.equal(kept[0], frames[cut]) and kept[2] is small.camera
