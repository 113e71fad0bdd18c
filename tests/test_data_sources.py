"""Dataset object sources (procedural, folder, pybullet, Objaverse mirror) and bad inputs."""

from __future__ import annotations

import gzip
import io
import json

import numpy as np
import pytest
import torch
import trimesh
from typer.testing import CliRunner

from reconphys.assets.ply import write_ply
from reconphys.assets.procedural import make_procedural_gaussians
from reconphys.cli import app
from reconphys.data import DropDataset, make_dataset, make_settings
from reconphys.data import objaverse as objaverse_module
from reconphys.data.objaverse import ObjaverseSource
from reconphys.data.sources import FolderSource, ProceduralSource, open_source
from reconphys.errors import InputError

runner = CliRunner()
TINY = dict(
    num_gaussians=300,
    num_anchors=48,
    num_neighbors=8,
    min_substeps=10,
    resolution=16,
    samples_per_object=1,
)
TINY_FLAGS = [
    "--num-gaussians",
    "300",
    "--num-anchors",
    "48",
    "--neighbors",
    "8",
    "--min-substeps",
    "10",
    "--resolution",
    "16",
    "--samples-per-object",
    "1",
    "--workers",
    "1",
    "--device",
    "cpu",
]


pytestmark = pytest.mark.usefixtures("no_network")


@pytest.fixture(autouse=True)
def _one_thread():
    # Small tensors gain nothing from threads, and spinning threads crawl on a busy machine.
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _coloured_sphere() -> trimesh.Trimesh:
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    colours = (np.abs(mesh.vertices) / 0.3 * 255).clip(30, 255).astype(np.uint8)
    mesh.visual.vertex_colors = np.concatenate([colours, np.full((len(colours), 1), 255)], 1)
    return mesh


@pytest.fixture
def mesh_folder(tmp_path):
    folder = tmp_path / "meshes"
    (folder / "nested").mkdir(parents=True)
    trimesh.creation.box(extents=(0.4, 0.3, 0.2)).export(folder / "box.obj")
    _coloured_sphere().export(folder / "nested" / "ball.glb")
    trimesh.creation.cylinder(radius=0.1, height=0.3).export(folder / "can.ply")
    write_ply(folder / "splat.ply", make_procedural_gaussians("torus", 500, seed=1))
    (folder / "notes.txt").write_text("not a mesh")
    return folder


def test_procedural_source_variants_are_stable():
    source = ProceduralSource()
    refs = source.candidates(10)
    assert len(refs) >= 10 and len({r.id for r in refs}) == len(refs)
    settings = make_settings(num_gaussians=200)
    a, b = source.load(refs[8], settings), source.load(refs[8], settings)
    assert torch.equal(a.means, b.means)
    extent = a.means.amax(0) - a.means.amin(0)
    assert extent.max().item() == pytest.approx(settings.size, rel=1e-5)
    assert source.describe(refs[8])["texture"] in ("checker", "stripes")


def test_folder_source_lists_meshes_and_gaussian_plys(mesh_folder):
    source = FolderSource(mesh_folder)
    refs = source.candidates(0)
    assert [r.id for r in refs] == ["box.obj", "can.ply", "nested/ball.glb", "splat.ply"]
    settings = make_settings(num_gaussians=200)
    for ref in refs:
        g = source.load(ref, settings)
        assert g.num_gaussians <= 500 and torch.isfinite(g.means).all()
        extent = (g.means.amax(0) - g.means.amin(0)).max().item()
        assert extent == pytest.approx(settings.size, rel=0.05), ref.id
    splat = source.load(refs[3], settings)  # a 3DGS PLY keeps (a subset of) its own Gaussians
    assert splat.num_gaussians == 200


def test_stretch_makes_an_ellipsoid_of_a_sphere(tmp_path):
    """--stretch: a sphere mesh stretched by s along an axis u is an ellipsoid whose extent along
    u is s times its extent across (analytic); drawn from the object id and the dataset seed."""
    from reconphys.data.source_base import load_file_object, mesh_stretch

    path = tmp_path / "ball.glb"
    _coloured_sphere().export(path)
    settings = make_settings(num_gaussians=2000, stretch_range=(2.0, 4.0), seed=5)
    assert mesh_stretch("ball.glb", make_settings()) is None
    stretch = mesh_stretch("ball.glb", settings)
    assert np.allclose(stretch, mesh_stretch("ball.glb", settings))  # the same for the same id
    other_seed = make_settings(stretch_range=(2.0, 4.0), seed=6)
    assert not np.allclose(stretch, mesh_stretch("ball.glb", other_seed))
    values, vectors = np.linalg.eigh(stretch)
    assert np.allclose(values[:2], 1.0) and 2.0 <= values[2] <= 4.0
    axis = torch.from_numpy(vectors[:, 2]).float()
    across = torch.from_numpy(vectors[:, 0]).float()
    g = load_file_object(path, "ball.glb", settings).means  # [N, 3], largest side settings.size
    along = g @ axis
    side = g @ across
    ratio = (along.max() - along.min()) / (side.max() - side.min())
    assert ratio.item() == pytest.approx(values[2], rel=0.04)
    plain = load_file_object(path, "ball.glb", make_settings(num_gaussians=2000)).means
    spread = plain.std(0)
    assert (spread.max() / spread.min()).item() < 1.1  # unstretched: still a sphere
    splat = tmp_path / "splat.ply"
    write_ply(splat, make_procedural_gaussians("torus", 100, seed=1))
    with pytest.raises(InputError, match="Gaussian PLY cannot be stretched"):
        load_file_object(splat, "splat.ply", settings)
    with pytest.raises(InputError, match="--stretch"):
        open_source("procedural", settings)
    with pytest.raises(InputError, match="--stretch"):
        make_settings(stretch_range=(0.5, 2.0))
    out = tmp_path / "d"
    result = runner.invoke(app, ["make-data", "--source", str(tmp_path), "--stretch", "0.5",
                                 "--out", str(out)])  # fmt: skip
    _assert_one_line_error(result, "--stretch", "1 ≤ low ≤ high")
    assert not out.exists()


def test_stretch_leaves_older_datasets_fingerprints_alone():
    """A dataset made before --stretch existed keeps its fingerprint (resumes and more_sources
    checks compare them); asking for a stretch changes it."""
    import hashlib

    settings = make_settings()
    values = settings.to_dict()
    values.pop("stretch_range")
    for name in ("scene", "object_size_range", "fov_range_deg", "elevation_range_deg"):
        values.pop(name)
    for name in (
        "framing_range",
        "noise_range",
        "video_quality_range",
        "vivid_share",
        "contrast_share",
        "hand_share",
        "grey_share",
        "exposure_range_s",
        "readout_range_s",
    ):
        values.pop(name)
    text = json.dumps(values, sort_keys=True)
    assert settings.fingerprint() == hashlib.sha256(text.encode()).hexdigest()[:16]
    assert make_settings(stretch_range=(1.0, 3.0)).fingerprint() != settings.fingerprint()


def test_pybullet_source():
    pytest.importorskip("pybullet_data")
    source = open_source("pybullet")
    refs = source.candidates(0)
    assert len(refs) > 100 and refs[0].id.startswith("random_urdfs/")
    g = source.load(refs[0], make_settings(num_gaussians=200))
    assert g.num_gaussians == 200


def test_pybullet_source_leaves_out_broken_meshes(tmp_path, monkeypatch):
    """pybullet's wheel ships random_urdfs/168/168.obj as the single line "v nan": the source
    must not list it (a plan drawing it killed a 1,360-sample run at its 229th object)."""
    import sys
    import types

    from reconphys.data import sources

    trimesh.creation.box(extents=(0.4, 0.3, 0.2)).export(tmp_path / "good.obj")
    (tmp_path / "bad.obj").write_text("v nan\n")
    fake = types.SimpleNamespace(getDataPath=lambda: str(tmp_path))
    monkeypatch.setitem(sys.modules, "pybullet_data", fake)
    monkeypatch.setattr(
        sources, "pybullet_mesh_paths", lambda: [tmp_path / "bad.obj", tmp_path / "good.obj"]
    )
    with pytest.warns(UserWarning, match=r"left out 1 unusable meshes: bad\.obj"):
        source = sources.PybulletSource()
    assert [ref.id for ref in source.candidates(1)] == ["good.obj"]


def _write_mirror(root, uids_with_files, uids_without_files):
    root.mkdir(parents=True)
    paths = {}
    for uid in uids_with_files + uids_without_files:
        paths[uid] = f"glbs/000-000/{uid}.glb"
    for uid in uids_with_files:
        (root / "glbs" / "000-000").mkdir(parents=True, exist_ok=True)
        _coloured_sphere().export(root / paths[uid])
    with gzip.open(root / "object-paths.json.gz", "wt") as f:
        json.dump(paths, f)
    return paths


def test_objaverse_mirror_is_read_locally(tmp_path, monkeypatch):
    def no_download(*args, **kwargs):
        raise AssertionError("downloaded without --download")

    monkeypatch.setattr(objaverse_module.urllib.request, "urlopen", no_download)
    root = tmp_path / "hf-objaverse-v1"
    _write_mirror(root, ["aaa111", "bbb222"], ["ccc333"])
    source = ObjaverseSource(root)
    refs = source.candidates(0)
    assert [r.id for r in refs] == ["objaverse/aaa111", "objaverse/bbb222"]
    assert source.load(refs[0], make_settings(num_gaussians=200)).num_gaussians == 200
    uids = tmp_path / "uids.txt"
    uids.write_text("bbb222\n")
    assert [r.id for r in ObjaverseSource(root, uids).candidates(0)] == ["objaverse/bbb222"]
    uids.write_text("zzz999\n")
    with pytest.raises(InputError, match="not in object-paths"):
        ObjaverseSource(root, uids)
    with pytest.raises(InputError, match="not an Objaverse mirror"):
        ObjaverseSource(tmp_path / "nowhere")


def test_objaverse_download_fetches_missing_objects(tmp_path, monkeypatch):
    root = tmp_path / "hf-objaverse-v1"
    _write_mirror(root, [], ["ccc333"])
    payload = io.BytesIO()
    _coloured_sphere().export(payload, file_type="glb")
    fetched = []

    class Response(io.BytesIO):
        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

    def fake_urlopen(url, timeout=None):
        fetched.append(url)
        return Response(payload.getvalue())

    monkeypatch.setattr(objaverse_module.urllib.request, "urlopen", fake_urlopen)
    with pytest.raises(InputError, match="use --download"):
        ObjaverseSource(root).candidates(0)
    source = ObjaverseSource(root, download=True)
    ref = source.candidates(0)[0]
    assert source.load(ref, make_settings(num_gaussians=200)).num_gaussians == 200
    assert fetched == [f"{objaverse_module.BASE_URL}/glbs/000-000/ccc333.glb"]
    assert (root / "glbs/000-000/ccc333.glb").is_file()


def test_make_data_from_objaverse_mirror(tmp_path):
    root = tmp_path / "hf-objaverse-v1"
    _write_mirror(root, ["aaa111"], [])
    settings = make_settings(source="objaverse", objects=1, **TINY)
    report = make_dataset(settings, tmp_path / "d", objaverse_root=root, device="cpu")
    assert report.manifest["complete"]
    assert report.manifest["samples"][0]["object"] == "objaverse/aaa111"


def test_make_data_from_mesh_folder(tmp_path, mesh_folder):
    out = tmp_path / "d"
    result = runner.invoke(
        app,
        [
            "make-data",
            "--source",
            str(mesh_folder),
            "--objects",
            "1",
            "--test-objects",
            "1",
            *TINY_FLAGS,
            "--test-samples-per-object",
            "1",
            "--out",
            str(out),
        ],
    )
    assert result.exit_code == 0, result.output
    dataset = DropDataset(out)
    assert sorted(s["split"] for s in dataset.samples) == ["test", "train"]


# --- bad inputs: one line naming the input, exit code 2, the dataset stays valid ---


def _assert_one_line_error(result, *fragments):
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.startswith("error: ")]
    assert len(lines) == 1, result.output
    assert "Traceback" not in result.output
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


def _assert_valid_dataset(out):
    dataset = DropDataset(out, allow_incomplete=True)  # every listed sample is complete
    for i in range(len(dataset)):
        assert dataset[i]["frames"].shape[0] == 4
    assert not list(out.glob("*/.*.staging-*"))


def test_empty_folder_is_a_clear_error(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    result = runner.invoke(
        app, ["make-data", "--source", str(empty), "--objects", "1", "--out", str(tmp_path / "d")]
    )
    _assert_one_line_error(result, str(empty), "no mesh files")


def test_missing_source_is_a_clear_error(tmp_path):
    missing = tmp_path / "nope"
    result = runner.invoke(app, ["make-data", "--source", str(missing), "--out", str(tmp_path)])
    _assert_one_line_error(result, str(missing), "not found")


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (b"\x00\x01garbage\xff" * 20, "bad.obj"),  # unreadable
        (b"v 0 0 0\nv 0 0 0\nv 0 0 0\nf 1 2 3\n", "bad.obj"),  # degenerate: zero area
    ],
)
def test_bad_mesh_is_a_clear_error_and_the_dataset_stays_valid(tmp_path, content, expected):
    folder = tmp_path / "meshes"
    folder.mkdir()
    trimesh.creation.box(extents=(0.4, 0.3, 0.2)).export(folder / "good.obj")
    (folder / "bad.obj").write_bytes(content)
    out = tmp_path / "d"
    result = runner.invoke(
        app,
        ["make-data", "--source", str(folder), "--objects", "2", "--out", str(out), *TINY_FLAGS],
    )
    _assert_one_line_error(result, expected)
    _assert_valid_dataset(out)
    with pytest.raises(InputError, match="incomplete"):
        DropDataset(out)


def test_too_few_objects_is_a_clear_error(tmp_path, mesh_folder):
    result = runner.invoke(
        app, ["make-data", "--source", str(mesh_folder), "--objects", "9", "--out", str(tmp_path)]
    )
    _assert_one_line_error(result, "has 4 objects, 9 asked for")
