"""Every thermal file a user has: each real sample reads to a raster (its raw counts, and °C where the camera
calibrates), FLIR's JPEG-LS raw images included; a file is what its bytes are, whatever its name; DJI's own format
in °C through DJI's real converter, each file at its own settings or the user's; a drone's folder of thermal and
visible photos keeps the thermal ones."""

from __future__ import annotations

import json
import os
import re
import shutil
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from real_data import RGBT_FRAMES, RJPEG_SAMPLES

from thermal_wild_ns.data import frame_files
from thermal_wild_ns.data.celsius import MeasurementSettings, dji_converter
from thermal_wild_ns.data.rjpeg import NotRadiometric, is_radiometric_jpeg, read_rjpeg
from thermal_wild_ns.data.thermal_io import read_raw_frame
from thermal_wild_ns.errors import InputError

needs_shared = pytest.mark.skipif(not RJPEG_SAMPLES.is_dir(), reason="../shared/data is not here")
SHARED_FILES = sorted(RGBT_FRAMES.glob("*.jpg")) + sorted(RJPEG_SAMPLES.glob("*.jpg")) if RJPEG_SAMPLES.is_dir() else []
DJI_SAMPLES = sorted(RJPEG_SAMPLES.glob("*_R.jpg")) if RJPEG_SAMPLES.is_dir() else []


def needs_converter():
    """DJI's converter must be here: the setup command installs it (CI runs it). Only where the person running
    the tests says it cannot be installed (THERMAL_WILD_NS_NO_DJI_CONVERTER=1) do its tests skip."""
    if dji_converter() is None:
        if os.environ.get("THERMAL_WILD_NS_NO_DJI_CONVERTER"):
            pytest.skip("DJI's converter not installed (THERMAL_WILD_NS_NO_DJI_CONVERTER)")
        pytest.fail("DJI's converter (dji-thermal-cli) is not installed: run the README's setup command")


@needs_shared
@pytest.mark.parametrize("path", SHARED_FILES, ids=lambda p: p.name)
def test_every_shared_thermal_file_reads_to_a_raster_and_in_celsius_where_its_camera_calibrates(path):
    raster = read_raw_frame(path)
    assert raster.ndim == 2 and raster.std() > 0  # a scene, not a constant
    if not is_radiometric_jpeg(path):  # an exported colour-mapped frame: its palette's levels, no °C
        assert raster.dtype == np.uint8
        with pytest.raises(NotRadiometric, match=re.escape(str(path))):
            read_rjpeg(path)
        return
    thermal = read_rjpeg(path)
    assert raster.dtype == np.uint16 and np.array_equal(raster, thermal.raw)  # the raw counts, not the preview
    if thermal.format == "dji":
        needs_converter()
    celsius = thermal.celsius()
    assert celsius.shape == raster.shape and np.isfinite(celsius).all()
    assert -70 < float(np.median(celsius)) < 300


# ExifTool 12.57's FLIR constants of the two JPEG-LS frames (`exiftool -s -FLIR:all FILE`; R1, R2, B, F, O, then
# emissivity, distance (m), reflected, atmospheric and IR window temperatures (°C), window transmission, humidity (%),
# atmosphere alpha1, alpha2, beta1, beta2, X)
EXIFTOOL = {
    "Dark_thermal.jpg": (13473.646, 0.025236322, 1368.2, 1.6, -7052),
    "Parterre_thermal.jpg": (12487.997, 0.024527194, 1345.6, 1.6, -6726),
}
EXIFTOOL_SETTINGS = (0.95, 1.0, 20.0, 20.0, 20.0, 1.0, 50.0, 0.006569, 0.012620, -0.002276, -0.006670, 1.9)


def planck_celsius(raw: np.ndarray, r1, r2, b, f, o, settings=EXIFTOOL_SETTINGS) -> np.ndarray:
    """The standard FLIR conversion (Thermimage's raw2temp), written out apart from the package's."""
    e, d, t_refl, t_atm, t_win, win, rh, a1, a2, b1, b2, x = settings
    h2o = rh / 100 * np.exp(1.5587 + 0.06939 * t_atm - 0.00027816 * t_atm**2 + 0.00000068455 * t_atm**3)
    tau = x * np.exp(-np.sqrt(d / 2) * (a1 + b1 * np.sqrt(h2o))) + (1 - x) * np.exp(
        -np.sqrt(d / 2) * (a2 + b2 * np.sqrt(h2o))
    )
    radiance = lambda c: r1 / (r2 * (np.exp(b / (c + 273.15)) - f)) - o
    raw_obj = (
        raw / e / tau / win / tau
        - (1 - tau) / e / tau * radiance(t_atm)
        - (1 - tau) / e / tau / win / tau * radiance(t_atm)
        - (1 - win) / e / tau / win * radiance(t_win)
        - (1 - e) / e * radiance(t_refl)
    )
    return b / np.log(r1 / (r2 * (raw_obj + o)) + f) - 273.15


@needs_shared
@pytest.mark.parametrize("name", sorted(EXIFTOOL))
def test_a_jpeg_ls_flir_frame_in_celsius_agrees_with_exiftools_constants(name):
    """FLIR's E-series stores its raw image as JPEG-LS: decoded, its counts follow the colour preview the camera
    drew from them, and its °C is ExifTool's constants applied to them, to 0.05 °C."""
    path = RGBT_FRAMES / name
    thermal = read_rjpeg(path)
    assert thermal.camera.endswith("FLIR E6xt Wifi") and thermal.raw.shape == (180, 240)
    expected = planck_celsius(thermal.raw.astype(np.float64), *EXIFTOOL[name])
    assert np.abs(thermal.celsius() - expected).max() <= 0.05
    # the decode itself: the preview (a palette drawn from the same counts) is brighter where they are higher
    preview = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2GRAY).astype(np.float64)
    counts = cv2.resize(thermal.raw.astype(np.float64), preview.shape[::-1], interpolation=cv2.INTER_LINEAR)
    assert np.corrcoef(counts.ravel(), preview.ravel())[0, 1] > 0.8


# ------------------------------------------------------------------ a file is what its bytes are
def _png16(path: Path) -> np.ndarray:
    frame = (np.arange(48 * 64, dtype=np.uint16).reshape(48, 64) * 7 + 1000).astype(np.uint16)
    assert cv2.imwrite(str(path.with_suffix(".png")), frame)
    path.with_suffix(".png").rename(path)
    return frame


def test_a_png_or_tiff_named_jpg_reads_as_what_it_is_said_once(tmp_path, monkeypatch):
    monkeypatch.setattr(frame_files, "_said", set())
    frame = _png16(tmp_path / "a.jpg")
    _png16(tmp_path / "b.jpg")
    tiff = tmp_path / "c.jpg"
    cv2.imwrite(str(tmp_path / "c.tiff"), frame)
    (tmp_path / "c.tiff").rename(tiff)
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        assert np.array_equal(read_raw_frame(tmp_path / "a.jpg"), frame)
        assert np.array_equal(read_raw_frame(tmp_path / "b.jpg"), frame)
        assert np.array_equal(read_raw_frame(tiff), frame)
    messages = [str(w.message) for w in said if "named .jpg" in str(w.message)]
    assert len(messages) == 2 and "content is PNG" in messages[0] and "content is TIFF" in messages[1]  # once each
    assert not is_radiometric_jpeg(tmp_path / "a.jpg")


@needs_shared
def test_a_radiometric_jpeg_named_png_reads_as_its_raw_counts(tmp_path, monkeypatch):
    monkeypatch.setattr(frame_files, "_said", set())
    for sample in (RJPEG_SAMPLES / "FLIR_E40.jpg", RJPEG_SAMPLES / "M3T_DJI_0002_R.jpg"):
        misnamed = tmp_path / f"{sample.stem}.png"
        shutil.copyfile(sample, misnamed)
        with pytest.warns(UserWarning, match=r"named \.png but its content is JPEG"):
            raster = read_raw_frame(misnamed)
        assert np.array_equal(raster, read_raw_frame(sample)) and raster.dtype == np.uint16
        monkeypatch.setattr(frame_files, "_said", set())
    plain = tmp_path / "grey.png"
    cv2.imwrite(str(tmp_path / "grey.jpg"), np.full((16, 16), 120, np.uint8))
    (tmp_path / "grey.jpg").rename(plain)
    raster = read_raw_frame(plain)  # a plain 8-bit JPEG named .png: its pixels
    assert raster.shape == (16, 16) and raster.dtype == np.uint8 and abs(int(raster.mean()) - 120) <= 1


# ------------------------------------------------------------------ DJI's format through DJI's converter
DISTANCE_AGAINST_PHYSICS = {"M2EA_DJI_0001_R.jpg": "its SDK's °C falls again past 5 m (34.4 at 5 m, 33.6 at 20 m)"}
"""Cameras whose °C DJI's own SDK moves against the atmosphere's correction as the distance grows (docs/rjpeg.md)."""


@needs_shared
def test_djis_converter_gives_each_dji_camera_its_celsius_and_follows_its_settings_as_physics_says():
    """The real converter on the 9 DJI samples: finite °C inside the camera's range; a surface read at a lower
    emissivity is warmer where it is warmer than its surroundings; read from farther, through more air, it is
    warmer where it is warmer than the air, on the cameras that take the air's temperature (the H20T, M30T and XT
    S record none: their SDK's own air temperature is not known) but the M2EA (`DISTANCE_AGAINST_PHYSICS`)."""
    needs_converter()
    for sample in DJI_SAMPLES:
        thermal = read_rjpeg(sample)
        embedded = thermal.celsius()
        assert embedded.shape == thermal.raw.shape and np.isfinite(embedded).all(), sample.name
        assert -40 <= float(embedded.min()) and float(embedded.max()) <= 550, sample.name
        # reflected and air temperature set below most of the scene: "warmer than the surroundings" is known
        cold = round(float(np.percentile(embedded, 5)) - 5.0, 1)
        at_95 = thermal.celsius(MeasurementSettings(0.95, None, cold, cold))
        warm = at_95 > cold + 5
        assert warm.mean() > 0.5, sample.name
        lower = thermal.celsius(MeasurementSettings(0.7, None, cold, cold))
        assert float(np.median(lower[warm] - at_95[warm])) > 0.5, sample.name
        near, far = (thermal.celsius(MeasurementSettings(0.95, d, cold, cold)) for d in (5.0, 20.0))
        takes_air = "DJI ZH20T" not in thermal.camera and thermal.camera not in ("DJI M30T", "DJI XT S")
        if takes_air and sample.name not in DISTANCE_AGAINST_PHYSICS:
            assert float(np.median(far[warm] - near[warm])) > 0.1, sample.name
    assert len(DJI_SAMPLES) == 9


@needs_shared
def test_a_farther_distance_than_the_camera_takes_is_clamped_and_said(monkeypatch):
    from thermal_wild_ns.data import celsius

    needs_converter()
    monkeypatch.setattr(celsius, "_told_clamped", set())
    thermal = read_rjpeg(RJPEG_SAMPLES / "M3T_DJI_0002_R.jpg")  # DJI's SDK takes 1-25 m for the M3T
    with pytest.warns(UserWarning, match=r"1-25 m for the DJI M3T: 25 m used .* not the 80 m asked"):
        far = thermal.celsius(MeasurementSettings(object_distance=80.0))
    assert np.array_equal(far, thermal.celsius(MeasurementSettings(object_distance=25.0)))


@needs_shared
def test_a_drone_folder_of_thermal_and_visible_photos_trains_on_the_thermal_ones_each_at_its_own_settings(tmp_path):
    """DJI samples as a survey (an OpenDroneMap project) with visible photos beside them: the visible ones left
    out and counted, each thermal frame's °C its own file's (the samples differ in their settings), and the
    held-out frames' °C scored through their own calibration."""
    import layout_fixtures as fx

    from thermal_wild_ns.data import layouts
    from thermal_wild_ns.data.dataparsers import ThermalDataParserConfig

    needs_converter()
    frames = [p for p in DJI_SAMPLES if read_rjpeg(p).raw.shape == (512, 640)]
    fx.write_odm(tmp_path / "survey", files=frames, size=(640, 512))
    images = tmp_path / "survey" / "images"
    for i in range(len(frames)):  # the drone's wide and zoom photos of the same shots
        for suffix in ("W", "Z"):
            cv2.imwrite(str(images / f"DJI_{i + 1:04d}_{suffix}.jpg"), np.full((60, 80, 3), 90 + i, np.uint8))
    assert layouts.detect_layout(tmp_path / "survey") == "odm"
    parser = ThermalDataParserConfig(data=tmp_path / "survey").setup()
    with pytest.warns(UserWarning, match=rf"{2 * len(frames)} visible photo\(s\) beside the {len(frames)} thermal"):
        capture = parser.capture()
    assert [f.image.name for f in capture.frames] == [f"DJI_{i + 1:04d}_T.jpg" for i in range(len(frames))]
    rng = parser.radiometric_range()
    settings = {read_rjpeg(p).camera for p in frames}
    assert len(settings) == len(frames)  # eight cameras, eight sets of settings
    for k, (frame, sample) in enumerate(zip(capture.frames, frames)):
        raw = read_raw_frame(frame.image)
        own = read_rjpeg(sample).celsius()
        assert np.abs(rng.to_celsius(rng.normalize(raw), frame=k) - own).max() < 1e-3, sample.name
    # the evaluation's °C of a held-out frame go through that frame's own calibration
    from functools import partial

    from thermal_wild_ns.pipeline.evaluation import scores

    held_out = next(k for k, f in enumerate(capture.frames) if f.split == "test")
    raw = rng.normalize(read_raw_frame(capture.frames[held_out].image))
    warmer = rng.normalize(read_raw_frame(capture.frames[held_out].image).astype(np.float64) + 20)
    result = scores(warmer, raw, partial(rng.to_celsius, frame=held_out))
    own = capture.frames[held_out].celsius
    expected = np.abs(own.celsius(rng.to_native(np.clip(warmer, 0, 1))) - own.celsius(rng.to_native(raw))).mean()
    assert result["celsius_mae"] == pytest.approx(expected, rel=1e-4)


def test_a_folder_of_visible_photos_alone_is_refused_saying_where_the_thermal_ones_are(tmp_path):
    from thermal_wild_ns.data.survey_frames import survey_frames

    (tmp_path / "images").mkdir()
    for i in range(3):
        cv2.imwrite(str(tmp_path / "images" / f"DJI_{i:04d}_W.jpg"), np.full((30, 40, 3), 100, np.uint8))
    with pytest.raises(InputError, match=r"3 image\(s\) are visible photos .*\*_T\.jpg / \*_R\.jpg"):
        survey_frames(tmp_path)


@needs_shared
@pytest.mark.slow  # trains through nerfstudio: a minute on a CPU
def test_a_dji_surveys_held_out_celsius_in_ns_eval_go_through_each_frames_own_calibration(tmp_path, monkeypatch):
    """`ns-train` on DJI frames (an OpenDroneMap project of the samples), then `ns-eval`: its `celsius_*` come,
    for every held-out frame, through that frame's own calibration (the converter's table for its file)."""
    import layout_fixtures as fx
    from nerfstudio.scripts.eval import ComputePSNR
    from ns_runs import STEPS, ns_train, run_args

    from thermal_wild_ns.pipeline import evaluation

    needs_converter()
    frames = [p for p in DJI_SAMPLES if read_rjpeg(p).raw.shape == (512, 640)]
    fx.write_odm(tmp_path / "survey", files=frames, size=(640, 512))
    out = tmp_path / "out"
    scale = ["--pipeline.datamanager.camera-res-scale-factor", "0.125"]
    ns_train([*run_args(out, STEPS, *scale), "odm-data", "--data", str(tmp_path / "survey")])
    asked, original = [], evaluation.scores

    def seen(pred, gt, to_celsius=None, device="cpu"):  # which frame's calibration each score's °C go through
        asked.append(to_celsius.keywords["frame"] if to_celsius is not None else "none")
        return original(pred, gt, to_celsius, device)

    monkeypatch.setattr(evaluation, "scores", seen)
    run = out / "x" / "wild-thermal" / "run"
    ComputePSNR(load_config=run / "config.yml", output_path=tmp_path / "eval.json").main()
    results = json.loads((tmp_path / "eval.json").read_text())["results"]
    assert all(np.isfinite(results[f"celsius_{m}_time"]) for m in ("mae", "rmse", "p95"))
    held_out = [k for k in range(len(frames)) if k % 8 == 0]  # every 8th frame, capture positions
    assert asked and set(asked) == set(held_out)  # every °C of the scores through a held-out frame's own
