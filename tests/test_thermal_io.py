"""Reading thermal frames: exact 16-bit values, palette inversion, one range per dataset, and
errors that name the file and the problem for every kind of bad input."""

import json
import os
import re
import threading

import cv2
import layout_fixtures as fx
import numpy as np
import pytest
from real_data import RGBT_FRAMES

from thermal_wild_ns.data import thermal_io
from thermal_wild_ns.data.dataparsers import ThermalDataParserConfig
from thermal_wild_ns.data.layouts import detect_layout
from thermal_wild_ns.data.palettes import PALETTE_NAMES, apply_palette, detect_palette, invert_palette, palette_rgb
from thermal_wild_ns.data.rjpeg import is_radiometric_jpeg
from thermal_wild_ns.data.thermal_io import load_npy, read_raw_frame, scan_frames
from thermal_wild_ns.errors import InputError


@pytest.mark.parametrize("suffix", [".png", ".tiff"])
def test_16bit_values_survive_exactly(tmp_path, suffix):
    raw = np.random.default_rng(0).integers(0, 65536, (37, 53), dtype=np.uint16)
    cv2.imwrite(str(tmp_path / f"f{suffix}"), raw)
    out = read_raw_frame(tmp_path / f"f{suffix}")
    assert out.dtype == np.uint16 and np.array_equal(out, raw)


def test_float_npy_temperatures(tmp_path):
    temps = np.linspace(-5.0, 80.0, 40 * 30, dtype=np.float32).reshape(30, 40)
    np.save(tmp_path / "t.npy", temps)
    assert np.array_equal(read_raw_frame(tmp_path / "t.npy"), temps)


def test_npy_reads_are_serialised_across_threads(tmp_path):
    # nerfstudio caches frames from a thread pool, and numpy parses .npy headers with the AST
    # constructor, which CPython 3.11 cannot run in two threads at once (CI once failed on it)
    array = np.arange(12, dtype=np.float32).reshape(3, 4)
    np.save(tmp_path / "a.npy", array)
    result = {}
    worker = threading.Thread(target=lambda: result.update(array=load_npy(tmp_path / "a.npy")))
    with thermal_io._NPY_HEADER_LOCK:  # another thread is parsing a header
        worker.start()
        worker.join(timeout=0.5)
        assert worker.is_alive() and "array" not in result  # waits for it
    worker.join(timeout=10)
    assert np.array_equal(result["array"], array)


@pytest.mark.parametrize("name", PALETTE_NAMES)
def test_palette_roundtrip_within_one_level(name, tmp_path):
    assert len({tuple(c) for c in palette_rgb(name)}) == 256  # every level has its own colour
    levels = np.arange(256, dtype=np.uint8).reshape(16, 16).repeat(3, 0)
    rgb = apply_palette(levels, name)
    back, distance = invert_palette(rgb, name)
    assert np.array_equal(back, levels) and float(distance.max()) == 0.0
    cv2.imwrite(str(tmp_path / "c.png"), rgb[..., ::-1])  # through a file, OpenCV's BGR included
    decoded = read_raw_frame(tmp_path / "c.png")  # grey is read as plain 8-bit, the others are detected
    assert np.abs(decoded.astype(int) - levels).max() <= 1


def test_palette_detected_through_jpeg_within_a_level(tmp_path):
    levels = fx.thermal_image(160, 120, 0, np.uint8)
    cv2.imwrite(str(tmp_path / "c.jpg"), apply_palette(levels, "inferno")[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])
    rng = scan_frames([tmp_path / "c.jpg"]).range
    assert rng.palette == "inferno"
    error = np.abs(read_raw_frame(tmp_path / "c.jpg", "inferno").astype(int) - levels)
    assert np.median(error) <= 1


def test_unknown_palette_is_refused(tmp_path):
    hue = np.tile(np.linspace(0, 179, 64).astype(np.uint8), (48, 1))  # an HSV rainbow
    image = cv2.cvtColor(np.dstack([hue, np.full_like(hue, 255), np.full_like(hue, 255)]), cv2.COLOR_HSV2BGR)
    cv2.imwrite(str(tmp_path / "rainbow.png"), image)
    with pytest.raises(ValueError, match=r"rainbow\.png: colour-mapped frame in an unknown palette"):
        read_raw_frame(tmp_path / "rainbow.png")


def test_normalisation_is_per_dataset_not_per_frame(tmp_path):
    cold = np.full((20, 30), 3600, np.uint16)
    warm = np.full((20, 30), 3900, np.uint16)
    cold[:, :15] += 100
    warm[:, :15] += 100
    for name, image in (("a.png", cold), ("b.png", warm)):
        cv2.imwrite(str(tmp_path / name), image)
    rng = scan_frames([tmp_path / "a.png", tmp_path / "b.png"], percentiles=(0.0, 100.0)).range
    assert (rng.low, rng.high) == (3600.0, 4000.0)
    a, b = rng.read(tmp_path / "a.png"), rng.read(tmp_path / "b.png")
    assert a.mean() == pytest.approx(0.125) and b.mean() == pytest.approx(
        0.875
    )  # per-frame min-max would give equal means


def test_frames_outside_the_range_are_named(tmp_path, recwarn):
    from thermal_wild_ns.data.thermal_io import RadiometricRange

    base = np.tile(np.linspace(3000, 3500, 64).astype(np.uint16), (48, 1))
    hot = base.copy()
    hot[:, -2:] = 4200  # 3 % of the pixels above the declared high end
    for name, image in (("a.png", base), ("b.png", hot), ("c.png", base)):
        cv2.imwrite(str(tmp_path / name), image)
    declared = RadiometricRange(2800.0, 3800.0, "uint16")
    scan_frames([tmp_path / "a.png", tmp_path / "c.png"], declared=declared)
    assert not recwarn.list  # frames inside the range: silent
    with pytest.warns(
        UserWarning,
        match=r"1 frame\(s\) have over 1% of their pixels above the declared radiometric range "
        r"\(above 3800\): b\.png\.",
    ):
        scan_frames(sorted(tmp_path.glob("*.png")), declared=declared)
    with pytest.warns(UserWarning, match=r"below the measured radiometric range .*: a\.png, b\.png, c\.png"):
        scan_frames(
            sorted(tmp_path.glob("*.png")), percentiles=(5.0, 100.0)
        )  # the lowest 5 % of every frame's pixels fall below


# --------------------------------------------------------------------------- bad input
def _parse(root, **kw):
    parser = ThermalDataParserConfig(data=root, seed_points="random", num_random_points=8, **kw).setup()
    return parser.get_dataparser_outputs("train")


def test_missing_image_names_it(tmp_path):
    fx.write_colmap(tmp_path / "s")
    (tmp_path / "s" / "images" / "frame_3.png").unlink()
    with pytest.raises(FileNotFoundError, match=r"frame_3\.png"):
        _parse(tmp_path / "s")


def test_unreadable_image_names_it(tmp_path):
    fx.write_colmap(tmp_path / "s")
    (tmp_path / "s" / "images" / "frame_5.png").write_bytes(b"not an image")
    with pytest.raises(ValueError, match=r"frame_5\.png: unreadable image file"):
        _parse(tmp_path / "s")


def test_pose_image_count_mismatch(tmp_path):
    fx.write_llff(tmp_path / "llff")
    cv2.imwrite(str(tmp_path / "llff" / "images" / "IMG_9999.png"), fx.thermal_image(64, 48, 0))
    with pytest.raises(ValueError, match=r"poses_bounds\.npy: 10 poses but 11 images.*count mismatch"):
        _parse(tmp_path / "llff")
    fx.write_ye(tmp_path / "ye")
    (tmp_path / "ye" / "train" / "pose" / "00002.txt").unlink()
    with pytest.raises(ValueError, match=r"train: 8 images in rgb/, 7 poses in pose/"):
        _parse(tmp_path / "ye")


@pytest.mark.parametrize("fault, message", [("nan", "non-finite"), ("scaled", "not rigid")])
def test_bad_pose_names_the_file_and_the_frame(tmp_path, fault, message):
    fx.write_thermalnerf(tmp_path / "s")
    meta = json.loads((tmp_path / "s" / "transforms.json").read_text())
    pose = np.array(meta["frames"][3]["transform_matrix"])
    pose[:3, :3] *= 1.5 if fault == "scaled" else 1.0
    pose[0, 3] = np.nan if fault == "nan" else pose[0, 3]
    meta["frames"][3]["transform_matrix"] = pose.tolist()
    (tmp_path / "s" / "transforms.json").write_text(json.dumps(meta))
    frame = re.escape(meta["frames"][3]["file_path"])
    with pytest.raises(ValueError, match=rf"transforms\.json, frame {frame}: camera pose .*{message}"):
        _parse(tmp_path / "s")


def test_mixed_bit_depths_name_the_file(tmp_path):
    fx.write_colmap(tmp_path / "s")
    cv2.imwrite(str(tmp_path / "s" / "images" / "frame_4.png"), fx.thermal_image(64, 48, 4, np.uint8))
    with pytest.raises(ValueError, match=r"frame_4\.png: pixel type uint8 differs from the dataset's uint16"):
        _parse(tmp_path / "s")


def test_wrong_size_names_the_file(tmp_path):
    fx.write_colmap(tmp_path / "s")
    cv2.imwrite(str(tmp_path / "s" / "images" / "frame_6.png"), fx.thermal_image(32, 48, 6))
    with pytest.raises(ValueError, match=r"frame_6\.png: image is 32x48 but its camera says 64x48"):
        _parse(tmp_path / "s")


def test_empty_sparse_model(tmp_path):
    fx.write_colmap(tmp_path / "s")
    fx.write_colmap_model(tmp_path / "s" / "sparse" / "0", [], [], np.eye(3), (64, 48))
    with pytest.raises(ValueError, match=r"sparse/0/images\.(bin|txt): the COLMAP model has no images"):
        _parse(tmp_path / "s")


def test_wrong_folder_lists_the_layouts_tried(tmp_path):
    (tmp_path / "photos").mkdir()
    with pytest.raises(ValueError, match=r"photos: not a thermal dataset layout") as err:
        detect_layout(tmp_path / "photos")
    for name in ("thermalnerf", "nerfstudio", "ye", "msx", "thermalmix", "mvtv", "llff", "colmap"):
        assert f"- {name} (" in str(err.value)
    fx.write_colmap(tmp_path / "colmap")
    with pytest.raises(FileNotFoundError, match=r"thermal"):
        _parse(tmp_path / "colmap", layout="msx")
    with pytest.raises(FileNotFoundError, match=r"nowhere: data folder not found"):
        _parse(tmp_path / "nowhere")


def test_constant_frames_have_no_range(tmp_path):
    for i in range(3):
        cv2.imwrite(str(tmp_path / f"c{i}.png"), np.full((8, 8), 3700, np.uint16))
    with pytest.raises(ValueError, match=r"every frame to measure the range from is degenerate"):
        scan_frames(sorted(tmp_path.glob("c*.png")))


def test_degenerate_frames_are_named_left_out_and_never_move_the_range(tmp_path):
    """An all-zero and a constant frame among real ones: reported by name, left out (or kept when
    asked), and the measured range is the one without them."""
    clean, faulty = tmp_path / "clean", tmp_path / "faulty"
    fx.write_nerfstudio(clean)
    fx.write_nerfstudio(faulty)
    cv2.imwrite(str(faulty / "images" / "0003.png"), np.zeros((48, 64), np.uint16))
    cv2.imwrite(str(faulty / "images" / "0005.png"), np.full((48, 64), 3700, np.uint16))
    scan = scan_frames(sorted((faulty / "images").glob("*.png")))
    assert scan.degenerate == [3, 5]
    others = [p for p in sorted((clean / "images").glob("*.png")) if p.name not in ("0003.png", "0005.png")]
    without = scan_frames(others).range  # the range of the same capture without those two frames
    assert scan.range == without
    assert scan_frames(sorted((clean / "images").glob("*.png"))).range != without  # (they would have moved it)

    def parser(root, **kw):
        return ThermalDataParserConfig(data=root, split="all", seed_points="random", num_random_points=8, **kw).setup()

    left_out = parser(faulty)
    names = [f.image.name for f in left_out.capture().frames]
    assert "0003.png" not in names and "0005.png" not in names and len(names) == 8
    assert left_out.radiometric_range() == without
    kept = parser(faulty, keep_degenerate_frames=True)
    assert len(kept.capture().frames) == 10 and kept.radiometric_range() == without


def test_a_cache_folder_published_twice_keeps_the_first_copy(tmp_path):
    from thermal_wild_ns.data.thermal_io import publish_cache_folder

    final = tmp_path / "preprocessed-abc"
    for name, text in (("first", "1"), ("second", "2")):  # two processes finishing the same cache folder
        work = tmp_path / f".work-{name}"
        work.mkdir()
        (work / "meta.json").write_text(text)
        publish_cache_folder(work, final, "meta.json")
        assert not work.exists()
    assert (final / "meta.json").read_text() == "1"
    # a folder in the way that is not a finished cache folder is an error, not silently kept
    other = tmp_path / "triangulation-x"
    (other / "junk").mkdir(parents=True)
    work = tmp_path / ".work-third"
    (work).mkdir()
    (work / "report.json").write_text("{}")
    with pytest.raises(OSError):
        publish_cache_folder(work, other, "report.json")
    assert (work / "report.json").is_file()  # nothing lost


@pytest.mark.parametrize(
    "own_file, content, message",
    [
        ("transforms.json", '{"frames": [1, 2,,]}', r"transforms\.json: not valid JSON"),
        ("transforms.json", "[]", r"transforms\.json: expected a JSON object with a 'frames' list"),
        ("poses_bounds.npy", "not numpy", r"poses_bounds\.npy: unreadable"),
    ],
)
def test_a_broken_layout_file_stops_detection(tmp_path, own_file, content, message):
    """A COLMAP model beside a broken transforms.json / poses_bounds.npy: detection reports the
    broken file instead of falling through to the COLMAP layout."""
    fx.write_colmap(tmp_path / "s")
    (tmp_path / "s" / own_file).write_text(content)
    with pytest.raises(ValueError, match=message):
        detect_layout(tmp_path / "s")
    (tmp_path / "s" / own_file).unlink()
    assert detect_layout(tmp_path / "s") == "colmap"  # the same folder without it is plain COLMAP


def test_stale_work_folders_of_dead_processes_are_removed_live_ones_kept(tmp_path):
    import subprocess
    import sys

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead_pid = int(dead.stdout)  # a process that has exited
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])  # a concurrent run
    try:
        for pid in (dead_pid, live.pid):
            (tmp_path / f".preprocessing-{pid}-abcd").mkdir()
            (tmp_path / f".preprocessing-{pid}-abcd" / "frame.npy").write_bytes(b"partial")
        (tmp_path / f".triangulation-{dead_pid}-abcd").mkdir()  # another stage's: not this call's business
        work = thermal_io.make_work_folder(tmp_path, ".preprocessing-")
        left = sorted(p.name for p in tmp_path.iterdir())
        assert f".preprocessing-{dead_pid}-abcd" not in left
        assert f".preprocessing-{live.pid}-abcd" in left and f".triangulation-{dead_pid}-abcd" in left
        assert work.is_dir() and work.name.startswith(f".preprocessing-{os.getpid()}-")
    finally:
        live.kill()


@pytest.mark.skipif(not RGBT_FRAMES.is_dir(), reason=f"{RGBT_FRAMES} (real RGBT-Scenes frames) is not here")
@pytest.mark.parametrize("frame", sorted(p.name for p in RGBT_FRAMES.glob("*.jpg")) if RGBT_FRAMES.is_dir() else [])
def test_real_rgbt_frames_decode_as_iron_monotonically(frame):
    """The 7 real colour-mapped frames: auto-detection picks iron (not jet, not a refusal), the
    levels span most of the palette, and they rise with the image's brightness (iron's luminance
    rises from its cold end to its hot end), so hot regions decode hotter than cold ones."""
    from scipy.stats import spearmanr

    path = RGBT_FRAMES / frame
    rgb = cv2.imread(str(path), cv2.IMREAD_COLOR)[..., ::-1]
    assert detect_palette(rgb, path) == "iron"
    if is_radiometric_jpeg(path):  # FLIR records behind the preview: its raw counts, unless a palette is named
        try:
            assert read_raw_frame(path).dtype == np.uint16
        except InputError as err:
            assert "JPEG-LS compressed" in str(err) and str(path) in str(err)
        levels = read_raw_frame(path, "iron")
    else:
        levels = read_raw_frame(path)  # the reader's own route: detection, then nearest-colour inversion
    low, high = np.percentile(levels, [1, 99])
    assert high - low >= 150, (low, high)
    luminance = rgb.astype(np.float64) @ [0.299, 0.587, 0.114]
    assert spearmanr(levels.ravel()[::7], luminance.ravel()[::7]).correlation > 0.98


def test_iron_table_rises_in_brightness_and_a_palette_is_judged_on_its_far_pixels(tmp_path):
    iron = palette_rgb("iron").astype(np.float64)
    assert np.all(np.diff(iron @ [0.299, 0.587, 0.114]) > 0)  # cold to hot is dark to bright
    image = apply_palette(np.tile(np.arange(256, dtype=np.uint8), (64, 1)), "iron")
    assert detect_palette(image, tmp_path / "a.jpg") == "iron"
    image[:, ::4] = (0, 255, 0)  # a quarter of the pixels in no palette: the median still fits iron exactly
    with pytest.raises(InputError, match=r"a\.jpg: colour-mapped frame in an unknown palette \(90th-percentile"):
        detect_palette(image, tmp_path / "a.jpg")
