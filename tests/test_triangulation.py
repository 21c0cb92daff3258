"""Gaussian seeds from the known poses: DUNR (poses, empty points3D.txt) gets triangulated points,
the cache is reused and never left half-written, and captures with nothing to triangulate fall
back to random points inside the cameras' view volume."""

import json

import layout_fixtures as fx
import numpy as np
import pytest
from real_data import DUNR

from thermal_wild_ns.data.dataparsers import ThermalDataParserConfig, random_view_volume_points
from thermal_wild_ns.data.layouts import detect_layout


@pytest.fixture(scope="module")
def dunr_cache(tmp_path_factory):
    if not DUNR.is_dir():
        pytest.skip(f"real DUNR scene not found at {DUNR} (it sits in ../shared beside the checkout)")
    return tmp_path_factory.mktemp("dunr-cache")


def test_dunr_gets_triangulated_points(dunr_cache):
    assert detect_layout(DUNR) == "nerfstudio"
    parser = ThermalDataParserConfig(data=DUNR, cache_dir=dunr_cache).setup()
    train = parser.get_dataparser_outputs("train")
    assert train.metadata["seed_points"]["source"] == "triangulated"
    (folder,) = dunr_cache.glob("triangulation-*")
    report = json.loads((folder / "report.json").read_text())
    errors = np.load(folder / "reprojection_errors.npy")
    assert report["points"] == train.metadata["seed_points"]["count"] >= 1000
    assert report["frames"] == 39  # training frames only: held-out views never shape the seeds
    assert (
        report["reprojection_error_px_median"] == pytest.approx(float(np.median(errors))) and np.median(errors) <= 2.0
    )
    # the seeds sit in front of the cameras, where the facade is (6-7 m away in metric units)
    xyz = np.load(folder / "points.npy")
    centre = np.mean([f.camera_to_world[:3, 3] for f in parser.capture().frames], axis=0)
    assert 3.0 < float(np.median(np.linalg.norm(xyz - centre, axis=1))) < 15.0
    # seeds carry thermal values sampled from the frames, not one constant
    assert len(np.unique(train.metadata["points3D_rgb"][:, 0].numpy())) > 50


def test_dunr_via_colmap_layout_reuses_the_cache(dunr_cache, monkeypatch):
    import thermal_wild_ns.data.triangulation as tri

    def fail(*args, **kwargs):
        raise AssertionError("triangulated again instead of reading the cache")

    monkeypatch.setattr(tri, "triangulate", fail)
    colmap = (
        ThermalDataParserConfig(data=DUNR, layout="colmap", cache_dir=dunr_cache)
        .setup()
        .get_dataparser_outputs("train")
    )
    transforms = (
        ThermalDataParserConfig(data=DUNR, layout="nerfstudio", cache_dir=dunr_cache)
        .setup()
        .get_dataparser_outputs("train")
    )
    # the COLMAP text model and transforms.json hold the same poses
    np.testing.assert_allclose(
        colmap.cameras.camera_to_worlds.numpy(), transforms.cameras.camera_to_worlds.numpy(), atol=1e-5
    )


def test_failed_triangulation_leaves_no_cache(tmp_path, monkeypatch):
    import pycolmap

    fx.write_colmap(tmp_path / "s")

    def crash(*args, **kwargs):
        raise RuntimeError("interrupted")

    monkeypatch.setattr(pycolmap, "triangulate_points", crash)
    config = ThermalDataParserConfig(data=tmp_path / "s", seed_points="triangulate", cache_dir=tmp_path / "cache")
    with pytest.raises(RuntimeError, match="interrupted"):
        config.setup().get_dataparser_outputs("train")
    left = [path.name for path in (tmp_path / "cache").iterdir()]
    assert [name for name in left if not name.startswith("scan-")] == []  # the frame scan, whole, kept apart


def test_textureless_capture_falls_back_to_random_seeds(tmp_path):
    import cv2

    root = tmp_path / "s"
    fx.write_colmap(root, with_point=False)
    for path in (root / "images").iterdir():  # flat frames: nothing for SIFT to find
        cv2.imwrite(str(path), np.full((48, 64), 3700, np.uint16) + np.arange(64, dtype=np.uint16)[None] // 16)
    outputs = (
        ThermalDataParserConfig(data=root, cache_dir=tmp_path / "cache", num_random_points=500)
        .setup()
        .get_dataparser_outputs("train")
    )
    assert outputs.metadata["seed_points"] == {"source": "random", "count": 500}
    with pytest.raises(ValueError, match="triangulation found only"):
        ThermalDataParserConfig(
            data=root, cache_dir=tmp_path / "cache", seed_points="triangulate"
        ).setup().get_dataparser_outputs("train")


def test_random_seeds_lie_in_front_of_the_cameras():
    poses = fx.cameras(6)
    frames = [
        type(
            "F", (), {"camera_to_world": c2w, "fx": 60.0, "fy": 60.0, "cx": 32.0, "cy": 24.0, "width": 64, "height": 48}
        )()
        for c2w in poses
    ]
    xyz = random_view_volume_points(frames, 2000)
    visible = 0
    for c2w in poses:
        cam = (xyz - c2w[:3, 3]) @ c2w[:3, :3]
        u = 60.0 * cam[:, 0] / cam[:, 2] + 32.0
        visible += np.sum((cam[:, 2] > 0) & (u >= 0) & (u <= 64))
    assert visible >= 2000  # every point is inside at least one camera's frustum (its own)
