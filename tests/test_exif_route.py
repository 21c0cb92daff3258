"""A drone survey with no photogrammetry: each frame's EXIF GPS and XMP gimbal angles as priors,
structure from motion (pycolmap) on the thermal frames, the result against Metashape's alignment
of the same frames (flight2), and clear errors where the files or SfM cannot do it."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from real_data import FLIGHT2, RJPEG_SAMPLES

from thermal_wild_ns.data import layouts, surveys
from thermal_wild_ns.data.exif import focal_length_px, gimbal_rotation, read_frame_prior
from thermal_wild_ns.data.rjpeg import radiometric_raw
from thermal_wild_ns.errors import InputError

needs_flight2 = pytest.mark.skipif(not FLIGHT2.is_dir(), reason="../shared/data/flight2 is not here")
needs_samples = pytest.mark.skipif(not RJPEG_SAMPLES.is_dir(), reason="no rjpeg_samples")


def test_gimbal_angles_turn_into_a_camera_pose_as_drones_report_them():
    east, north, up = np.eye(3)
    nadir = gimbal_rotation(0.0, -90.0, 0.0)  # columns: the camera's x (right), y (down), z (forward)
    assert np.allclose(nadir[:, 2], -up) and np.allclose(-nadir[:, 1], north)  # image top to the north
    assert np.allclose(gimbal_rotation(90.0, -90.0, 0.0)[:, 1], -east)  # heading east: image top to the east
    level = gimbal_rotation(0.0, 0.0, 0.0)
    assert np.allclose(level[:, 2], north) and np.allclose(level[:, 1], -up) and np.allclose(level[:, 0], east)
    assert gimbal_rotation(0.0, 0.0, 10.0)[2, 0] < 0  # rolled right: the camera's right side goes down
    assert gimbal_rotation(0.0, 20.0, 0.0)[2, 2] > 0  # pitched up: looks above the horizon
    r = gimbal_rotation(37.0, -61.0, 4.0)
    assert np.allclose(r.T @ r, np.eye(3)) and np.linalg.det(r) == pytest.approx(1.0)


@needs_flight2
def test_a_frames_own_metadata_gives_its_position_and_gimbal():
    prior = read_frame_prior(FLIGHT2 / "rjpeg" / "DJI_0199.jpg")
    # exiftool: GPS 46 deg 23' 51.61" N, 6 deg 14' 17.66" E, 398.3 m; GimbalYaw 119.9, Pitch -89.9, Roll 0
    assert prior.latitude == pytest.approx(46 + 23 / 60 + 51.6108 / 3600)
    assert prior.longitude == pytest.approx(6 + 14 / 60 + 17.6576 / 3600)
    assert (prior.altitude, prior.yaw, prior.pitch, prior.roll) == pytest.approx((398.3, 119.9, -89.9, 0.0), abs=1e-4)
    # the XT writes its focal length in mm only, and no field of view
    assert focal_length_px(FLIGHT2 / "rjpeg" / "DJI_0199.jpg", 640, 512) == (None, "")


@needs_samples
@pytest.mark.parametrize(
    "name, expected, source",
    [
        # 35 mm equivalent 40 mm on the diagonal (CIPA): 9.1 mm / 12 um pixels = 758 px
        ("M3T_DJI_0002_R.jpg", 40.0 * math.hypot(640, 512) / math.hypot(36, 24), "EXIF 35 mm equivalent"),
        ("FLIR_T640.jpg", 320 / math.tan(math.radians(24.988414764404297 / 2)), "FLIR field of view"),
    ],
)
def test_the_focal_length_comes_from_what_the_file_records(name, expected, source):
    path = RJPEG_SAMPLES / name
    height, width = radiometric_raw(path).shape
    focal, found_in = focal_length_px(path, width, height)
    assert focal == pytest.approx(expected, rel=1e-4) and found_in == source


def _geotagged_noise(folder: Path, n: int) -> None:
    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(n):
        exif = Image.Exif()
        exif[0x8825] = {1: "N", 2: (46.0, 23.0, 51.6 + 0.1 * i), 3: "E", 4: (6.0, 14.0, 17.6), 6: 398.3}
        Image.fromarray(rng.integers(0, 255, (96, 128), dtype=np.uint8)).save(folder / f"DJI_{i:04d}_T.jpg", exif=exif)


def test_frames_sfm_cannot_place_are_an_error_saying_what_it_found(tmp_path):
    _geotagged_noise(tmp_path / "survey" / "images", 6)  # noise: nothing matches between frames
    assert layouts.detect_layout(tmp_path / "survey") == "exif-gps"
    with pytest.raises(InputError, match=r"placed \d of 6 frames .* SIFT features per frame.*metashape-data"):
        surveys.read_exif_gps(tmp_path / "survey", cache_root=tmp_path / "cache")
    assert not list((tmp_path / "cache").glob("sfm-*"))  # nothing half-written is kept


def test_a_frame_without_gps_is_named(tmp_path):
    folder = tmp_path / "survey" / "images"
    folder.mkdir(parents=True)
    Image.fromarray(np.zeros((8, 8), np.uint8)).save(folder / "plain_T.jpg")
    assert read_frame_prior(folder / "plain_T.jpg") is None
    with pytest.raises(InputError, match="exif-gps.*plain_T.jpg has no GPS position") as refused:
        layouts.detect_layout(tmp_path / "survey")
    assert "exif-gps" in str(refused.value)
    with pytest.raises(InputError, match=r"images: none of its 1 frames has a GPS position in its EXIF"):
        surveys.read_exif_gps(tmp_path / "survey", cache_root=tmp_path / "cache")


@needs_flight2
@pytest.mark.slow  # two SfM runs on flight2: about a minute on two cores
def test_flight2_placed_from_its_exif_lies_close_to_metashapes_alignment(tmp_path):
    from experiments.exif_vs_metashape import compare

    plain = compare(FLIGHT2, None, tmp_path)
    assert plain["frames_exif_route"] == plain["frames_compared"] == 32
    assert plain["before_registration"]["centre_distance_m"]["median"] < 10  # the GPS's own error
    assert plain["before_registration"]["gimbal_prior_rotation_deg"]["median"] < 8
    assert plain["registered"]["centre_distance_m"]["median"] < 1.0
    assert plain["registered"]["rotation_deg"]["median"] < 5.0
    # with the camera's lens calibration (made before the flight) SfM's geometry is Metashape's
    calibrated = compare(FLIGHT2, FLIGHT2 / "metashape" / "FlirModel_XT.xml", tmp_path)
    assert calibrated["registered"]["centre_distance_m"]["median"] < 0.3
    assert calibrated["registered"]["rotation_deg"]["median"] < 1.0
