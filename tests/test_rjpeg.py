"""Radiometric JPEGs: the raw counts and °C of every camera in `../shared/data/rjpeg_samples`, the
source's own temperature rasters of flight2 reproduced, and clear errors for JPEGs without
thermal data."""

from __future__ import annotations

import dataclasses
import io
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from real_data import FLIGHT2, RJPEG_SAMPLES

from thermal_wild_ns.data.celsius import DJI_CONVERTER_ENV, DjiCalibration, NoCelsiusDecoder, dji_converter
from thermal_wild_ns.data.rjpeg import NotRadiometric, is_radiometric_jpeg, read_rjpeg
from thermal_wild_ns.errors import InputError

needs_shared = pytest.mark.skipif(not RJPEG_SAMPLES.is_dir(), reason="../shared/data is not here")


def _exiftool(sample: Path) -> dict:
    """The sample's ExifTool dump, `Tag Name : value` lines."""
    dump = {}
    for line in sample.with_suffix(".exif.txt").read_text(encoding="utf8").splitlines():
        name, _, value = line.partition(":")
        dump.setdefault(name.strip(), value.strip())
    return dump


def _number(text: str) -> float:
    return float(re.match(r"-?[0-9.]+", text).group(0))


SAMPLE_FILES = sorted(p.name for p in RJPEG_SAMPLES.glob("*.jpg")) if RJPEG_SAMPLES.is_dir() else []


@needs_shared
@pytest.mark.parametrize("name", SAMPLE_FILES)
def test_every_camera_gives_its_raw_raster_and_celsius_or_says_what_to_install(name, monkeypatch):
    sample = RJPEG_SAMPLES / name
    dump = _exiftool(sample)
    thermal = read_rjpeg(sample)
    assert is_radiometric_jpeg(sample)
    assert thermal.raw.dtype == np.uint16 and thermal.raw.std() > 0  # a scene, not a constant
    if "Raw Thermal Image Width" in dump:  # FLIR format: the raster and calibration ExifTool reads
        assert thermal.format == "flir"
        assert thermal.raw.shape == (int(dump["Raw Thermal Image Height"]), int(dump["Raw Thermal Image Width"]))
        celsius = thermal.celsius()
        assert celsius.shape == thermal.raw.shape and np.isfinite(celsius).all()
        assert -100 < float(np.median(celsius)) < 200
    else:  # DJI format: the raster's size is ExifTool's 'Thermal Data' at the preview's aspect ratio
        assert thermal.format == "dji" and thermal.camera.startswith("DJI")
        pixels = int(re.search(r"Binary data (\d+) bytes", dump["Thermal Data"]).group(1)) // 2
        if dump["Camera Model Name"] == "XT S":  # its raster is in APP4; ExifTool's 'Thermal Data' is its APP3 part
            pixels = int(dump["Image Width"]) * int(dump["Image Height"])
        preview = int(dump["Image Width"]) / int(dump["Image Height"])
        height, width = thermal.raw.shape
        assert height * width == pixels and width / height == pytest.approx(preview)
        # DJI's converter not installed: the file, the camera and the command that installs it
        monkeypatch.setenv(DJI_CONVERTER_ENV, "/nonexistent/dji-thermal-cli")
        install = "pipx install --python python3.12 dji-thermal-cli"
        what = rf"{re.escape(str(sample))}: a DJI-format R-JPEG \(DJI .+\).*{install}"
        with pytest.raises(NoCelsiusDecoder, match=what):
            thermal.celsius()


@needs_shared
@pytest.mark.parametrize("name", [n for n in SAMPLE_FILES if not re.search(r"_R\.jpg$", n)])
def test_the_flir_calibration_equals_exiftools(name):
    sample = RJPEG_SAMPLES / name
    dump, cal = _exiftool(sample), read_rjpeg(RJPEG_SAMPLES / name).calibration
    for tag, value in (
        ("Planck R1", cal.planck_r1),
        ("Planck R2", cal.planck_r2),
        ("Planck B", cal.planck_b),
        ("Planck F", cal.planck_f),
        ("Planck O", cal.planck_o),
        ("Emissivity", cal.emissivity),
        ("Object Distance", cal.object_distance),
        ("Reflected Apparent Temperature", cal.reflected_temperature - 273.15),
        ("Atmospheric Temperature", cal.atmospheric_temperature - 273.15),
        ("Relative Humidity", cal.relative_humidity * 100),
        ("Atmospheric Trans Alpha 1", cal.alpha1),
        ("Atmospheric Trans X", cal.atmospheric_trans_x),
    ):
        expected = _number(dump[tag])
        assert value == pytest.approx(expected, rel=1e-6, abs=0.051), tag  # ExifTool prints 0.1 °C, 0.01 m


@needs_shared
@pytest.mark.parametrize("frame", ["DJI_0199", "DJI_0207", "DJI_0215", "DJI_0223"])
def test_flight2s_reference_temperatures_are_reproduced(frame):
    """The source's rasters (milli-°C, uint16) were made with a 1 m object distance; the files
    store 20 m. At the same setting the decoder reproduces them; at the file's own it does not,
    so the test would notice a decoder that ignored the distance."""
    thermal = read_rjpeg(FLIGHT2 / "rjpeg" / f"{frame}.jpg")
    reference = cv2.imread(str(FLIGHT2 / "reference_mK" / f"{frame}.tiff"), cv2.IMREAD_UNCHANGED) / 1000.0
    assert thermal.camera == "DJI FLIR" and thermal.raw.shape == reference.shape == (512, 640)
    as_made = dataclasses.replace(thermal.calibration, object_distance=1.0).celsius(thermal.raw)
    assert np.abs(as_made - reference).max() <= 0.05
    assert thermal.calibration.object_distance == 20.0
    assert np.abs(thermal.celsius() - reference).max() > 0.05


# ------------------------------------------------------------------ JPEGs without thermal data
def _jpeg(make: str = "") -> bytes:
    from PIL import Image

    image = Image.fromarray(np.random.default_rng(0).integers(0, 255, (48, 64, 3), dtype=np.uint8))
    exif = Image.Exif()
    if make:
        exif[0x010F], exif[0x0110] = make, "ZH20T"
    out = io.BytesIO()
    image.save(out, "JPEG", exif=exif.tobytes())
    return out.getvalue()


@pytest.mark.parametrize("make", ["", "DJI"])
def test_a_jpeg_without_thermal_data_is_named_never_read_as_its_preview(tmp_path, make):
    path = tmp_path / "DJI_0001_V.jpg"
    path.write_bytes(_jpeg(make))
    assert not is_radiometric_jpeg(path)
    with pytest.raises(NotRadiometric, match=rf"{re.escape(str(path))}: no radiometric data .*colour preview"):
        read_rjpeg(path)


@needs_shared
def test_a_damaged_rjpeg_names_the_file(tmp_path):
    data = (FLIGHT2 / "rjpeg" / "DJI_0199.jpg").read_bytes()
    cut = tmp_path / "cut.jpg"
    cut.write_bytes(data[:30000])  # inside the FLIR segments
    with pytest.raises(InputError, match=re.escape(str(cut))):
        read_rjpeg(cut)
    other = tmp_path / "not.jpg"
    cv2.imwrite(str(tmp_path / "x.png"), np.zeros((8, 8), np.uint8))
    other.write_bytes((tmp_path / "x.png").read_bytes())
    with pytest.raises(InputError, match=rf"{re.escape(str(other))}: not a JPEG"):
        read_rjpeg(other)


@needs_shared
def test_a_calibrated_range_scores_in_celsius():
    from thermal_wild_ns.data.thermal_io import RadiometricRange
    from thermal_wild_ns.pipeline.evaluation import scores

    thermal = read_rjpeg(FLIGHT2 / "rjpeg" / "DJI_0199.jpg")
    rng = RadiometricRange(2400.0, 3400.0, "uint16", planck=thermal.calibration)
    assert rng.has_celsius and not RadiometricRange(0.0, 1.0, "uint16").has_celsius
    normalised = rng.normalize(thermal.raw)
    np.testing.assert_allclose(rng.to_celsius(normalised), thermal.celsius(), atol=1e-4)
    hotter = rng.normalize(thermal.raw.astype(np.float64) + 10)  # 10 counts more everywhere
    result = scores(hotter, normalised, rng.to_celsius)
    per_count = np.abs(thermal.calibration.celsius(thermal.raw + 10.0) - thermal.celsius())  # [H, W] °C
    assert result["celsius_mae"] == pytest.approx(per_count.mean(), rel=1e-3)
    assert result["celsius_mae"] <= result["celsius_rmse"] <= result["celsius_p95"] + 1e-6
    assert "celsius_mae" not in scores(hotter, normalised)


FAKE_CONVERTER = """#!{python}
# dji-thermal-cli's interface ('process --input-dir --output-dir', <stem>_temp_c.tiff) with a known formula
import sys, pathlib, cv2, numpy as np
from thermal_wild_ns.data.rjpeg import read_rjpeg
args = sys.argv
if args[1] == "list":  # no camera ranges listed
    sys.exit(0)
source, target = (pathlib.Path(args[args.index(flag) + 1]) for flag in ("--input-dir", "--output-dir"))
target.mkdir(parents=True, exist_ok=True)
for path in sorted(source.glob("*.jpg")):
    cv2.imwrite(str(target / f"{{path.stem}}_temp_c.tiff"), read_rjpeg(path).raw.astype(np.float32) * 0.01 - 150.0)
"""


def _fake_converter(tmp_path: Path, monkeypatch) -> None:
    import sys

    script = tmp_path / "dji-thermal-cli"
    script.write_text(FAKE_CONVERTER.format(python=sys.executable))
    script.chmod(0o755)
    monkeypatch.setenv(DJI_CONVERTER_ENV, str(script))


@needs_shared
def test_dji_files_read_in_celsius_through_djis_converter_where_it_is_installed(tmp_path, monkeypatch):
    from thermal_wild_ns.data.survey_frames import survey_celsius
    from thermal_wild_ns.data.thermal_io import RadiometricRange

    _fake_converter(tmp_path, monkeypatch)
    sample = read_rjpeg(RJPEG_SAMPLES / "M3T_DJI_0002_R.jpg")
    assert np.allclose(sample.celsius(), sample.raw * 0.01 - 150.0, atol=1e-3)
    # a survey's frames: each frame's own table, and one over all of them for renders at no frame's state
    frames = [RJPEG_SAMPLES / "M3T_DJI_0002_R.jpg", RJPEG_SAMPLES / "M3TD_DJI_0001_R.jpg"]
    table, own = survey_celsius(frames, RJPEG_SAMPLES)
    assert isinstance(table, DjiCalibration) and "2 file(s)" in table.source
    raws = [read_rjpeg(p).raw for p in frames]
    for calibration, raw in zip(own, raws):
        assert calibration.raw[0] == raw.min() and calibration.raw[-1] == raw.max()
    everything = np.concatenate([r.ravel() for r in raws])
    assert table.raw[0] == everything.min() and table.raw[-1] == everything.max()
    beyond = np.array([everything.min() - 100.0, everything.max() + 100.0])  # linear beyond the table's ends
    assert np.allclose(table.celsius(beyond), beyond * 0.01 - 150.0, atol=1e-3)
    rng = RadiometricRange(float(everything.min()), float(everything.max()), "uint16", planck=table)
    assert rng.has_celsius and rng.to_celsius(np.array([0.0, 1.0])) == pytest.approx(
        [everything.min() * 0.01 - 150.0, everything.max() * 0.01 - 150.0], abs=1e-3
    )
    # without the converter: raw counts, and the log says how to have °C
    monkeypatch.setenv(DJI_CONVERTER_ENV, "/nonexistent/dji-thermal-cli")
    with pytest.warns(UserWarning, match="without °C.*setup command"):
        assert survey_celsius(frames, RJPEG_SAMPLES) == (None, [None, None])


@needs_shared
@pytest.mark.skipif(dji_converter() is None, reason="DJI's converter (dji-thermal-cli) is not installed")
def test_djis_own_converter_gives_plausible_celsius_for_every_dji_camera(tmp_path):
    """On every DJI-format camera: the converter's own raw raster is ours (x1, or x0.25 where DJI
    stores 14-bit counts shifted by two bits), its °C is one value per raw count (so one table per
    survey holds), our °C is its °C exactly, and warmer counts are warmer."""
    import subprocess

    samples = sorted(RJPEG_SAMPLES.glob("*_R.jpg"))
    subprocess.run(
        [dji_converter(), "process", "--input-dir", str(RJPEG_SAMPLES), "--output-dir", str(tmp_path)]
        + ["--output", "temp_c:tiff,raw:tiff", "--distance", "embedded", "--quiet"],
        check=True,
        capture_output=True,
    )
    for sample in samples:
        thermal = read_rjpeg(sample)
        theirs_raw = cv2.imread(str(tmp_path / f"{sample.stem}_raw.tiff"), cv2.IMREAD_UNCHANGED).astype(np.float64)
        theirs_c = cv2.imread(str(tmp_path / f"{sample.stem}_temp_c.tiff"), cv2.IMREAD_UNCHANGED)
        ours = thermal.raw.astype(np.float64)
        assert np.array_equal(theirs_raw, ours) or np.array_equal(theirs_raw, ours * 0.25), sample.name
        _, per_count = np.unique(thermal.raw.ravel(), return_inverse=True)
        spread = np.zeros(per_count.max() + 1)
        np.maximum.at(spread, per_count, theirs_c.ravel() - theirs_c.ravel().min())
        low = np.full(per_count.max() + 1, np.inf)
        np.minimum.at(low, per_count, theirs_c.ravel() - theirs_c.ravel().min())
        assert np.allclose(spread, low), sample.name  # one °C per raw count
        celsius = thermal.celsius()
        assert np.array_equal(celsius, theirs_c), sample.name
        assert -40 < float(np.median(celsius)) < 120
        order = np.argsort(thermal.raw.ravel(), kind="stable")
        assert (np.diff(celsius.ravel()[order]) >= -1e-4).all()  # warmer counts, warmer °C
