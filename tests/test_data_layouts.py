"""Every published thermal layout loads with the right poses, intrinsics and splits.

Each fixture (tests/layout_fixtures.py, which cites the published facts it mirrors) stores the
same known cameras in its layout's convention; after parsing, a known 3D point must reproject to
the pixel the true camera sees it at, in every layout and split.
"""

import json

import layout_fixtures as fx
import numpy as np
import pytest
import torch

from thermal_wild_ns.data.capture import fraction_split
from thermal_wild_ns.data.dataparsers import ThermalDataParserConfig
from thermal_wild_ns.data.layouts import detect_layout
from thermal_wild_ns.data.thermal_io import read_raw_frame


def reproject(outputs, index: int, point: np.ndarray) -> np.ndarray:
    """Pixel of a world point in parsed camera `index` (nerfstudio: OpenGL axes, transformed world)."""
    p = torch.from_numpy(np.append(point, 1.0)).float()
    x = (outputs.dataparser_transform @ p) * outputs.dataparser_scale
    c2w = outputs.cameras.camera_to_worlds[index]
    cam = c2w[:3, :3].T @ (x - c2w[:3, 3])
    cams = outputs.cameras
    u = cams.fx[index, 0] * cam[0] / -cam[2] + cams.cx[index, 0]
    v = cams.fy[index, 0] * -cam[1] / -cam[2] + cams.cy[index, 0]
    return np.array([float(u), float(v)])


CASES = {
    # layout: (writer, folder name, expected held-out indices in capture order, n)
    "thermalnerf": (fx.write_thermalnerf, "scene", [8]),  # nerfstudio's 'fraction' rule on 10 frames at 0.9
    "ye": (fx.write_ye, "seq01", [4, 9]),
    "llff": (fx.write_llff, "scene", [0, 8]),
    "mvtv": (lambda root: fx.write_llff(root, folder="thermal"), "scene", [0, 8]),
    "msx": (fx.write_msx, "scene", [0, 8]),
    "thermalmix": (fx.write_thermalmix, "lion", [20]),
    "colmap": (fx.write_colmap, "scene", [0, 8, 16]),
}


@pytest.mark.parametrize("layout", sorted(CASES))
def test_layout_poses_intrinsics_and_split(layout, tmp_path):
    writer, folder, held_out = CASES[layout]
    root = tmp_path / folder
    truth = writer(root)
    assert detect_layout(root) == layout
    for name in (layout, "auto"):
        parser = ThermalDataParserConfig(data=root, layout=name, seed_points="random", num_random_points=64).setup()
        train, test = parser.get_dataparser_outputs("train"), parser.get_dataparser_outputs("test")
        assert train.metadata["layout"] == layout
        assert train.metadata["frame_indices"] == [i for i in range(len(truth)) if i not in held_out]
        assert test.metadata["frame_indices"] == held_out
        for outputs in (train, test):
            for k, i in enumerate(outputs.metadata["frame_indices"]):
                c2w, K = truth[i]
                expected = fx.project(c2w, K)
                np.testing.assert_allclose(
                    reproject(outputs, k, fx.KNOWN_POINT), expected, atol=2e-3, err_msg=f"{layout} frame {i}"
                )
                assert float(outputs.cameras.fx[k]) == pytest.approx(K[0, 0], rel=1e-6)
                assert float(outputs.cameras.cy[k]) == pytest.approx(K[1, 2], rel=1e-6)


def test_thermalnerf_uses_thermal_frames_only(tmp_path):
    fx.write_thermalnerf(tmp_path / "s")
    outputs = (
        ThermalDataParserConfig(data=tmp_path / "s", layout="thermalnerf", seed_points="random", num_random_points=8)
        .setup()
        .get_dataparser_outputs("train")
    )
    assert all(p.parent.name == "images_thermal" for p in outputs.image_filenames)
    assert int(outputs.cameras.width[0]) == 64 and outputs.metadata["thermal_range"].dtype == "uint8"


def test_msx_iron_jpgs_decode_to_levels(tmp_path):
    from thermal_wild_ns.pipeline.datamanager import ThermalDataset

    fx.write_msx(tmp_path / "s")
    outputs = (
        ThermalDataParserConfig(data=tmp_path / "s", layout="msx", seed_points="random", num_random_points=8)
        .setup()
        .get_dataparser_outputs("train")
    )
    rng = outputs.metadata["thermal_range"]
    assert rng.palette == "iron" and rng.dtype == "uint8"
    image = ThermalDataset(outputs).get_image_float32(0)[..., 0].numpy()
    truth = rng.normalize(fx.thermal_image(640, 480, 1, np.uint8))  # frame 0 is held out: index 0 is frame 1
    # JPEG-compressed colours invert to within a couple of levels; the median is within one
    error_levels = np.abs(image - truth) * (rng.high - rng.low)
    assert np.median(error_levels) <= 1.0 and np.percentile(error_levels, 95) <= 3.0


def test_thermalmix_keeps_published_celsius_bounds(tmp_path):
    fx.write_thermalmix(tmp_path / "lion")
    parser = ThermalDataParserConfig(
        data=tmp_path / "lion", layout="thermalmix", seed_points="random", num_random_points=8
    ).setup()
    rng = parser.get_dataparser_outputs("train").metadata["thermal_range"]
    assert (rng.low, rng.high, rng.celsius_low, rng.celsius_high) == (0.0, 255.0, 16.8, 48.3)
    assert rng.to_celsius(np.array([0.0, 1.0])).tolist() == [16.8, 48.3]


def test_colmap_text_model_and_sfm_seeds(tmp_path):
    fx.write_colmap(tmp_path / "s", binary=False, extra_points=7)
    outputs = ThermalDataParserConfig(data=tmp_path / "s", layout="colmap").setup().get_dataparser_outputs("train")
    assert outputs.metadata["seed_points"] == {"source": "colmap", "count": 8}
    xyz = outputs.metadata["points3D_xyz"]
    expected = (outputs.dataparser_transform @ torch.tensor([*fx.KNOWN_POINT, 1.0]).float()) * outputs.dataparser_scale
    assert float((xyz - expected).norm(dim=-1).min()) < 1e-5  # the known point, in the parsed world


def test_layouts_train_through_the_datamanager(tmp_path):
    """What `ns-train wild-thermal <parser> --data X` does before the first step: the datamanager
    caches every frame as float [H, W, 1]."""
    from thermal_wild_ns.pipeline.datamanager import ThermalDatamanagerConfig

    for layout, (writer, folder, _) in CASES.items():
        root = tmp_path / layout / folder
        writer(root)
        config = ThermalDatamanagerConfig(
            dataparser=ThermalDataParserConfig(data=root, layout=layout, seed_points="random", num_random_points=32)
        )
        datamanager = config.setup(device="cpu")
        camera, batch = datamanager.next_train(0)
        assert batch["image"].ndim == 3 and batch["image"].shape[-1] == 1 and batch["image"].dtype == torch.float32, (
            layout
        )
        assert int(camera.height) == batch["image"].shape[0], layout


def test_frames_cached_on_the_host_train_without_cuda(tmp_path):
    """nerfstudio caches frames on the host when asked (`cache_images='cpu'`) and whenever a capture
    has over 500 training frames, and pins them for copies to a GPU: a torch without CUDA refuses
    to pin ("Cannot access accelerator device"), which ended a 1,000-frame survey's set-up on a CPU.
    Without CUDA the frames stay unpinned on the CPU."""
    from thermal_wild_ns.pipeline.datamanager import ThermalDatamanagerConfig

    if torch.cuda.is_available():
        pytest.skip("pinning works where CUDA is: the path under test is a CPU-only torch's")
    root = tmp_path / "s"
    fx.write_thermalnerf(root)
    parser = ThermalDataParserConfig(data=root, layout="thermalnerf", seed_points="random", num_random_points=32)
    datamanager = ThermalDatamanagerConfig(dataparser=parser, cache_images="cpu").setup(device="cpu")
    camera, batch = datamanager.next_train(0)
    assert batch["image"].device.type == "cpu" and not batch["image"].is_pinned()
    assert batch["image"].shape == (int(camera.height), int(camera.width), 1)


def test_distorted_thermal_frames_are_undistorted_single_channel(tmp_path):
    """ThermalNeRF frames carry k1, k2, p1, p2: nerfstudio undistorts them when caching, and the
    frames must stay [H, W, 1] (OpenCV returns 1-channel images as [H, W])."""
    import json

    from thermal_wild_ns.pipeline.datamanager import ThermalDatamanagerConfig
    from thermal_wild_ns.preprocessing.photometric import PhotometricConfig

    fx.write_thermalnerf(tmp_path / "s")
    meta = json.loads((tmp_path / "s" / "transforms.json").read_text())
    for frame in meta["frames"]:
        frame.update(k1=0.05, p1=0.001)
    (tmp_path / "s" / "transforms.json").write_text(json.dumps(meta))
    parser = ThermalDataParserConfig(
        data=tmp_path / "s", layout="thermalnerf", seed_points="random", num_random_points=32
    )
    # raw frames: the training images cached are then the frames as recorded, undistorted
    datamanager = ThermalDatamanagerConfig(dataparser=parser, preprocessing=PhotometricConfig("none")).setup(
        device="cpu"
    )
    camera, batch = datamanager.next_train(0)
    assert float(camera.distortion_params[0, 0]) == pytest.approx(0.05)
    assert batch["image"].shape == (int(camera.height), int(camera.width), 1)
    # a frame read again from disk (held-back and held-out targets) is undistorted as the cache was
    for dataset, cache in (
        (datamanager.train_dataset, datamanager.cached_train),
        (datamanager.eval_dataset, datamanager.cached_eval),
    ):
        for k in range(len(dataset)):
            recorded, original = dataset.recorded_image(k), dataset.original_image(k)
            assert np.array_equal(recorded, cache[k]["image"][..., 0].numpy())
            assert recorded.shape != original.shape or not np.array_equal(recorded, original)  # it was distorted


def test_a_sparse_model_too_small_to_seed_is_not_used(tmp_path):
    """One SfM point cannot initialise Gaussians (scales come from 3 neighbours): 'auto' seeds
    otherwise, 'sfm' says why it cannot."""
    fx.write_colmap(tmp_path / "s")  # KNOWN_POINT only
    auto = (
        ThermalDataParserConfig(data=tmp_path / "s", layout="colmap", num_random_points=50)
        .setup()
        .get_dataparser_outputs("train")
    )
    assert auto.metadata["seed_points"]["source"] != "colmap" and auto.metadata["seed_points"]["count"] >= 4
    with pytest.raises(ValueError, match="seed_points='sfm' but the colmap layout has only 1 sparse points"):
        ThermalDataParserConfig(data=tmp_path / "s", layout="colmap", seed_points="sfm").setup().get_dataparser_outputs(
            "train"
        )


@pytest.mark.parametrize(
    "num_frames, fraction, held_out",
    [(10, 0.9, [8]), (45, 0.9, [10, 21, 32, 43]), (7, 0.5, [1, 3, 5]), (5, 1.0, [])],
)
def test_fraction_split_is_nerfstudios_rule(num_frames, fraction, held_out):
    from nerfstudio.data.utils.dataparsers_utils import get_train_eval_split_fraction

    split = fraction_split(num_frames, fraction)
    assert [i for i, s in enumerate(split) if s == "test"] == held_out
    _, i_eval = get_train_eval_split_fraction([f"{i}.png" for i in range(num_frames)], fraction)
    assert i_eval.tolist() == held_out  # and nerfstudio's own code agrees


@pytest.mark.parametrize("fmt", ["jpg", "npy"])
def test_thermalmix_reads_warped_thermal_and_drops_missing_frames_before_the_holdout(tmp_path, fmt):
    """As the authors' loader: the warped frames (never the unwarped thermal/), and the held-out
    index counts only the images that have a frame."""
    fx.write_thermalmix(tmp_path / "lion", fmt=fmt, missing=[5])
    parser = ThermalDataParserConfig(
        data=tmp_path / "lion", layout="thermalmix", seed_points="random", num_random_points=8
    ).setup()
    with pytest.warns(UserWarning, match=r"1 of the 24 images .* have no frame"):
        capture = parser.capture()
    assert len(capture.frames) == 23
    assert all(f.image.parent.name == "warped_thermal" and f.image.suffix == f".{fmt}" for f in capture.frames)
    assert [f.image.stem for f in capture.frames if f.split == "test"] == ["IMG_021"]  # view 20 of the 23
    raw = read_raw_frame(capture.frames[0].image).astype(np.float64)
    warped = fx.thermal_image(80, 60, 0, np.uint8).astype(np.float64)
    if fmt == "npy":
        warped = 16.8 + warped * (48.3 - 16.8) / 255
        assert parser.radiometric_range().celsius_low == 16.8
    assert np.abs(raw - warped).mean() < 0.05 * np.ptp(warped)  # the warped frame's pixels, not thermal/'s


def test_thermalnerf_missing_point_cloud_warns_and_seeds_otherwise(tmp_path):
    fx.write_thermalnerf(tmp_path / "scene")
    meta = json.loads((tmp_path / "scene" / "transforms.json").read_text())
    meta["ply_file_path"] = "sparse_pc.ply"  # named in transforms.json, but not shipped
    (tmp_path / "scene" / "transforms.json").write_text(json.dumps(meta))
    parser = ThermalDataParserConfig(
        data=tmp_path / "scene", layout="thermalnerf", seed_points="random", num_random_points=8
    ).setup()
    with pytest.warns(UserWarning, match=r"ply_file_path sparse_pc\.ply is missing; seeds from --seed-points"):
        outputs = parser.get_dataparser_outputs("train")
    assert outputs.metadata["seed_points"]["source"] == "random"


def test_ti_nsd_is_detected_by_its_numeric_names_and_sorted_as_3dgs_does(tmp_path):
    fx.write_ti_nsd(tmp_path / "scene")
    assert detect_layout(tmp_path / "scene") == "ti-nsd"

    def held_out(layout):
        parser = ThermalDataParserConfig(
            data=tmp_path / "scene", layout=layout, seed_points="random", num_random_points=8
        ).setup()
        return [f.image.stem for f in parser.capture().frames if f.split == "test"]

    # 3DGS sorts image names as strings (1, 10, ..., 19, 2, 20, 3, ...) and holds out every 8th from the first
    assert held_out("ti-nsd") == ["1", "17", "6"]
    assert held_out("colmap") == ["1", "9", "17"]  # the generic reader's natural order
    fx.write_colmap(tmp_path / "plain")  # frame_0.png ...: not numeric, so plain COLMAP
    assert detect_layout(tmp_path / "plain") == "colmap"


def test_mvtv_is_marked_layout_unconfirmed(tmp_path):
    """No public source confirms MVTV's release layout: --help and the detection message say so."""
    from thermal_wild_ns.data.dataparsers import mvtv_dataparser

    assert "layout unconfirmed" in mvtv_dataparser.description
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match=r"- mvtv \(MVTV \(Xu et al\.\): layout unconfirmed"):
        detect_layout(tmp_path / "empty")


def test_a_second_setup_reads_the_scan_kept_and_a_changed_frame_is_read_again(tmp_path, monkeypatch):
    """The commands after training set the dataparser up again: the frame scan (every frame read, the range
    measured) is kept per set of frame files and settings, said again with its warnings, and a frame rewritten
    makes a new scan."""
    from pathlib import Path

    import cv2

    import thermal_wild_ns.data.dataparsers as dataparsers

    root = tmp_path / "scene"
    fx.write_nerfstudio(root)

    def parse(parsed=None):
        config = ThermalDataParserConfig(data=root, seed_points="random", num_random_points=16, cache_dir=tmp_path)
        parser = config.setup()
        parser.get_dataparser_outputs("train")
        return parser.radiometric_range() if parsed is None else parsed(parser)

    held_out = parse(lambda parser: [f.image for f in parser.capture().frames if f.split == "test"])
    frame = Path(held_out[0])
    image = cv2.imread(str(frame), cv2.IMREAD_UNCHANGED)
    image[:, : image.shape[1] // 2] = 60000  # a held-out frame far above the range: named in a warning
    cv2.imwrite(str(frame), image)

    with pytest.warns(UserWarning, match=frame.name):
        first = parse()
    assert len(list(tmp_path.glob("scan-*.json"))) == 2  # the frames before and after the edit
    scans = []
    original = dataparsers.scan_frames
    monkeypatch.setattr(dataparsers, "scan_frames", lambda *a, **k: scans.append(a[0]) or original(*a, **k))
    with pytest.warns(UserWarning, match=frame.name):  # said again from the kept scan
        again = parse()
    assert again == first and not scans  # no frame scanned again
    cv2.imwrite(str(frame), np.full_like(image, 3000))  # the frame rewritten: a new key
    changed = parse()
    assert len(scans) == 1 and len(list(tmp_path.glob("scan-*.json"))) == 3
    assert changed == parse(lambda parser: parser.radiometric_range())  # kept in turn


def test_a_scan_that_cannot_be_kept_is_still_given_and_leaves_no_partial_file(tmp_path, monkeypatch):
    """A cache folder that cannot take the scan (a full disk, here the rename failing) keeps nothing, half-written
    or whole, and the scan is given all the same."""
    import thermal_wild_ns.data.scan_cache as scan_cache
    from thermal_wild_ns.data.thermal_io import FrameScan, RadiometricRange

    def refused(*args):
        raise OSError("No space left on device")

    monkeypatch.setattr(scan_cache.os, "replace", refused)
    scan = FrameScan(RadiometricRange(low=1.0, high=2.0, dtype="uint16"), [])
    assert scan_cache.cached_scan(tmp_path / "cache", "key", lambda: scan) is scan
    assert list((tmp_path / "cache").iterdir()) == []
