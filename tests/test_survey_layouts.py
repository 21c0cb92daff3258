"""Drone surveys from their photogrammetry: Metashape (flight2: poses in a local east-north-up frame
with the georeference kept, Metashape's distortion in OpenCV's order, frames read as radiometric
JPEGs, cameras landing where the GPS put them) and OpenDroneMap / OpenSfM (a project made in code)."""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest
from real_data import FLIGHT2

from thermal_wild_ns.data import layouts, surveys
from thermal_wild_ns.data.capture import validate
from thermal_wild_ns.data.georeference import datum_to_wgs84, ecef_to_geodetic
from thermal_wild_ns.data.rjpeg import NotRadiometric
from thermal_wild_ns.data.thermal_io import read_raw_frame
from thermal_wild_ns.errors import InputError

needs_flight2 = pytest.mark.skipif(not FLIGHT2.is_dir(), reason="../shared/data/flight2 is not here")


@needs_flight2
def test_flight2_is_detected_and_read_as_a_georeferenced_nadir_survey():
    assert layouts.detect_layout(FLIGHT2) == "metashape"
    capture = validate(surveys.read_metashape(FLIGHT2))
    assert [f.image.name for f in capture.frames] == sorted(p.name for p in (FLIGHT2 / "rjpeg").glob("*.jpg"))
    assert [f.split for f in capture.frames][:9] == ["test"] + ["train"] * 7 + ["test"]
    centres = np.array([f.camera_to_world[:3, 3] for f in capture.frames])  # [32, 3] metres, east-north-up
    assert np.ptp(centres[:, :2], axis=0).max() > 40 and np.ptp(centres[:, 2]) < 5  # flown level over the site
    looking = np.array([f.camera_to_world[:3, 2] for f in capture.frames])  # OpenCV z: the viewing direction
    assert (looking[:, 2] < -0.95).all()  # nadir: every camera looks down
    geo = capture.georeference
    # Lake Geneva's north shore (LV95 ~2'507'700 / 1'139'150), ~346 m above sea + ~50 m geoid
    assert 46.3 < geo.latitude < 46.5 and 6.1 < geo.longitude < 6.4 and 380 < geo.height < 420
    assert 'EPSG","2056' in geo.crs_wkt
    frame = capture.frames[0]
    # Metashape's P1, P2 are OpenCV's p2, p1 (Agisoft's camera model): nerfstudio order k1..k4, p1, p2
    assert frame.distortion[4:] == pytest.approx([0.0038518362275804805, 0.0086626298488847245])
    assert (frame.width, frame.height, frame.cx) == (640, 512, pytest.approx(320 + 10.090000975425118))
    raw = read_raw_frame(frame.image)  # the sensor's counts, not the colour preview
    assert raw.dtype == np.uint16 and raw.shape == (512, 640) and 2000 < raw.min() < raw.max() < 3500


def test_the_datum_shift_and_geodetic_conversion():
    # WGS84 (no TOWGS84): identity; CH1903+: the published 3-parameter shift
    assert np.array_equal(datum_to_wgs84(None), np.eye(4))
    shift = datum_to_wgs84('DATUM["CH1903+",TOWGS84[674.374,15.056,405.346,0,0,0,0]]')
    assert shift[:3, 3] == pytest.approx([674.374, 15.056, 405.346]) and np.allclose(shift[:3, :3], np.eye(3))
    assert ecef_to_geodetic(np.array([6378137.0, 0.0, 0.0])) == pytest.approx((0.0, 0.0, 0.0), abs=1e-6)
    lat, lon, h = ecef_to_geodetic(np.array([0.0, 6378137.0 + 100.0, 0.0]))
    assert (lat, lon, h) == pytest.approx((0.0, 90.0, 100.0), abs=1e-6)
    lat, lon, h = np.radians(46.4), np.radians(6.24), 400.0  # flight2's site, forward by the textbook formula
    e2 = 6.69437999014e-3
    n = 6378137.0 / np.sqrt(1 - e2 * np.sin(lat) ** 2)
    xyz = [(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon), (n * (1 - e2) + h) * np.sin(lat)]
    assert ecef_to_geodetic(np.array(xyz)) == pytest.approx((46.4, 6.24, 400.0), abs=1e-6)


@needs_flight2
def test_a_survey_of_colour_previews_is_refused_naming_the_file(tmp_path):
    root = tmp_path / "survey"
    (root / "rjpeg").mkdir(parents=True)
    shutil.copytree(FLIGHT2 / "metashape", root / "metashape")
    preview = cv2.imread(str(FLIGHT2 / "rjpeg" / "DJI_0199.jpg"))  # the colour preview only, re-encoded
    cv2.imwrite(str(root / "rjpeg" / "DJI_0199.jpg"), preview)
    with pytest.raises(
        InputError, match=r"rjpeg: its 1 image\(s\) are visible photos \(DJI_0199\.jpg.*without thermal"
    ):
        surveys.read_metashape(root)
    # named as DJI names its thermal frames, the preview is refused for what it lacks
    from thermal_wild_ns.data.survey_frames import survey_celsius

    named = root / "rjpeg" / "DJI_0199_T.jpg"
    (root / "rjpeg" / "DJI_0199.jpg").rename(named)
    with pytest.raises(NotRadiometric, match=r"DJI_0199_T\.jpg: no radiometric data"):
        survey_celsius([named], named.parent)


@needs_flight2
def test_the_cameras_land_where_metashapes_references_put_them():
    """Local east-north-up -> the project's CRS (LV95) through the recorded georeference: the camera
    centres Metashape aligned fall on the positions the drone's GPS gave (its <reference> x, y, z)."""
    import xml.etree.ElementTree as ET

    from thermal_wild_ns.export.survey import SurveyFrame

    capture = surveys.read_metashape(FLIGHT2)
    survey = SurveyFrame(capture.georeference)
    assert survey.crs.to_epsg() == 2056
    chunk = ET.parse(FLIGHT2 / "metashape" / "chunk_doc.xml").getroot()
    gps = {c.get("label"): c.find("reference") for c in chunk.iter("camera")}
    centres = np.array([f.camera_to_world[:3, 3] for f in capture.frames])
    projected = survey.to_crs(centres)  # [32, 3] easting, northing, ellipsoidal height
    reference = np.array([[float(gps[f.image.stem].get(k)) for k in "xy"] for f in capture.frames])
    assert np.median(np.linalg.norm(projected[:, :2] - reference, axis=1)) < 3.0  # GPS-grade agreement


def test_an_opendronemap_project_is_detected_and_read_with_its_georeference(tmp_path):
    import layout_fixtures as fx

    from thermal_wild_ns.data.georeference import geodetic_to_ecef

    truth = fx.write_odm(tmp_path / "survey", n=12)
    assert layouts.detect_layout(tmp_path / "survey") == "odm"
    capture = validate(surveys.read_odm(tmp_path / "survey"))
    assert [f.image.name for f in capture.frames] == [f"DJI_{i + 1:04d}.png" for i in range(12)]
    for frame, (c2w, K) in zip(capture.frames, truth):
        np.testing.assert_allclose(frame.camera_to_world, c2w, atol=1e-9)
        assert (frame.fx, frame.fy, frame.cx, frame.cy) == pytest.approx((K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
        # the fixture's known point lands where the reconstruction's camera says
        np.testing.assert_allclose(fx.project(frame.camera_to_world, frame.intrinsics_matrix()), fx.project(c2w, K))
    assert capture.points.xyz.shape == (40, 3) and capture.points.source == "opensfm"
    geo = capture.georeference
    assert (geo.latitude, geo.longitude, geo.height) == pytest.approx((46.4, 6.24, 400.0), abs=1e-6)
    assert geo.crs_wkt is None
    np.testing.assert_allclose(geo.origin_ecef, geodetic_to_ecef(46.4, 6.24, 400.0))
    assert [f.split for f in capture.frames][:9] == ["test"] + ["train"] * 7 + ["test"]


def test_the_export_commands_load_without_rasterio():
    """rasterio (GDAL, PROJ) is needed where a survey has a georeference: the export commands load without it, so
    a capture without one (a walked building, a generated survey) exports its °C points on an install that lacks
    it, as the GPU image's bundle did."""
    import subprocess
    import sys

    script = "import sys\nsys.modules['rasterio'] = None\nimport thermal_wild_ns.export.commands\nprint('ok')\n"
    loaded = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert loaded.returncode == 0 and loaded.stdout.strip() == "ok", loaded.stderr[-1500:]
