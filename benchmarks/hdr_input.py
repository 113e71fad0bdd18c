"""An HDR phone video read as SDR, against the same frames as SDR (docs/usage.md, HDR).

For view 0 of the first ``--limit`` test samples of a realistic-look dataset, the stored frames
are written again as HEVC 10-bit: as SDR (BT.709), and as HLG and PQ by ITU-R BT.2100's formulas
(tests/test_capture_hdr.bt2100_codes, independent of the reader); each is read back by
``read_video`` — the HDR ones as SDR (the default) and, with ``--as-stored``, as they are stored
(the reading before 2026-12-03) — and segmented by the shipped mask segmenter. Prints per clip
and in the mean the mask IoU against the true masks and the frames' mean |difference| from the
stored SDR frames (levels of 255).

``--chroma 444 --lossless`` isolates the reading; ``--chroma 420`` (``--crf``, default 18) is
what a phone writes.

    python benchmarks/hdr_input.py data/real_other [--limit 20] [--chroma 420|444] [--lossless]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import torch
from common import machine_description, mean_mask_iou

import reconphys.capture.video as video
from reconphys.data import DropDataset
from reconphys.models.mask_segmenter import load_mask_segmenter, rated_segment_clip

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_capture_hdr import bt2100_codes  # BT.2100's formulas, in numpy

TRANSFERS = {"hlg": "arib-std-b67", "pq": "smpte2084", "sdr": "bt709"}


def write_hevc(frames: np.ndarray, path: Path, look: str, chroma: str, crf: str, lossless: bool):
    """[T, H, W, 3] sRGB uint8 → a 10-bit HEVC file of ``look`` (sdr, hlg, pq), tagged."""
    count, height, width = frames.shape[:3]
    params = ":lossless=1" if lossless else ""
    if look == "sdr":  # ffmpeg's own conversion to BT.709 Y'CbCr, the output so tagged
        source, pixels = ["-pix_fmt", "rgb24"], frames.tobytes()
        convert = ["-vf", f"scale=out_color_matrix=bt709:out_range=tv,format=yuv{chroma}p10le"]
        primaries, matrix = "bt709", "bt709"
    else:
        codes = bt2100_codes(frames, look.upper())  # [T, 3, H, W] Y'CbCr 4:4:4
        luma, colour = codes[:, 0], codes[:, 1:]
        source = ["-pix_fmt", f"yuv{chroma}p10le", "-color_range", "tv"]
        if chroma == "420":  # each 2 × 2 block's mean, its chroma sited at the block's centre
            colour = colour.reshape(count, 2, height // 2, 2, width // 2, 2).mean((3, 5))
            colour = np.rint(colour).astype("<u2")
            source += ["-chroma_sample_location", "center"]
            params += ":chromaloc=1"
        pixels = b"".join(luma[t].tobytes() + colour[t].tobytes() for t in range(count))
        convert = []
        primaries, matrix = "bt2020", "bt2020nc"
    tags = ["-color_primaries", primaries, "-color_trc", TRANSFERS[look], "-colorspace", matrix]
    params = f"colorprim={primaries}:transfer={TRANSFERS[look]}:colormatrix={matrix}" + params
    command = [imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-y", "-f", "rawvideo"]
    command += [*source, "-s", f"{width}x{height}", "-r", "33.333"]
    command += [*(tags if look != "sdr" else []), "-i", "-", *convert, *tags]
    command += ["-c:v", "libx265", "-crf", crf, "-x265-params", params + ":log-level=error"]
    subprocess.run([*command, "-tag:v", "hvc1", str(path)], input=pixels, check=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("data", help="a realistic-look dataset (make-data --scene realistic)")
    parser.add_argument("--limit", type=int, default=20)
    parser.add_argument("--chroma", choices=["420", "444"], default="420")
    parser.add_argument("--crf", default="18")
    parser.add_argument("--lossless", action="store_true")
    parser.add_argument("--as-stored", action="store_true", help="HDR read as stored (before)")
    args = parser.parse_args()
    torch.set_num_threads(2)
    print(f"# {' '.join(sys.argv)}\n# {machine_description('cpu')}")
    if args.as_stored:  # the reading before 2026-12-03: no HDR curve recognised
        video.hdr_transfer = lambda path: None
    dataset = DropDataset(args.data, views=[0], verify=False, split="test")
    segmenter = load_mask_segmenter()
    looks = ["sdr", "hlg", "pq"]
    iou = {k: [] for k in ["stored", *looks]}
    diff = {k: [] for k in looks}
    with tempfile.TemporaryDirectory() as tmp:
        for index in range(min(args.limit, len(dataset))):
            item = dataset[index]
            frames, truth = item["frames"][0].float(), dataset.masks(index)[0].float()
            stored = (frames.clamp(0, 1) * 255 + 0.5).to(torch.uint8).numpy()
            masks = rated_segment_clip(segmenter, frames)[0]
            iou["stored"].append(mean_mask_iou(masks.float(), truth))
            for look in looks:
                path = Path(tmp) / f"{look}.mov"
                write_hevc(stored, path, look, args.chroma, args.crf, args.lossless)
                read = video.read_video(path)[0][..., :3]
                diff[look].append(float(np.abs(read.astype(int) - stored.astype(int)).mean()))
                masks = rated_segment_clip(segmenter, torch.from_numpy(read).float() / 255)[0]
                iou[look].append(mean_mask_iou(masks.float(), truth))
            print(
                f"{item['id'][:40]:40s} IoU "
                + " ".join(f"{k} {v[-1]:.3f}" for k, v in iou.items())
                + " |diff| "
                + " ".join(f"{k} {v[-1]:.2f}" for k, v in diff.items()),
                flush=True,
            )
    print(
        f"mean over {len(iou['stored'])} clips: IoU "
        + " ".join(f"{k} {np.mean(v):.4f}" for k, v in iou.items())
        + "; |diff| "
        + " ".join(f"{k} {np.mean(v):.2f}" for k, v in diff.items())
    )


if __name__ == "__main__":
    main()
