"""Dataset diagnostics: each measure on inputs whose answer is known, and the command end to end."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from real_data import FLIGHT2

from thermal_wild_ns.analysis.diagnostics import (
    high_frequency_ratio,
    radial_power_spectrum,
    relative_mean_change,
    tracked_features,
    used_dynamic_range,
)


def test_relative_mean_change():
    np.testing.assert_allclose(relative_mean_change([90.0, 100.0, 110.0]), [-0.1, 0.0, 0.1])
    with pytest.raises(ValueError, match="mean intensity is zero"):
        relative_mean_change([0.0, 0.0])


def test_power_spectrum_separates_smooth_from_noisy():
    rng = np.random.default_rng(0)
    v, u = np.mgrid[0:64, 0:96]
    smooth = np.sin(u / 15.0) + np.cos(v / 11.0)
    noise = rng.standard_normal((64, 96))
    freqs, p_smooth = radial_power_spectrum(smooth)
    _, p_noise = radial_power_spectrum(noise)
    assert freqs.shape == p_smooth.shape == (64,)
    assert high_frequency_ratio(freqs, p_smooth) < 0.01 < 0.5 < high_frequency_ratio(freqs, p_noise)
    # unit white noise: flat spectrum at power 1 per frequency (Parseval, with our 1/size scaling)
    assert np.mean(p_noise[8:]) == pytest.approx(1.0, rel=0.1)
    assert np.mean(p_noise[8:30]) == pytest.approx(np.mean(p_noise[30:]), rel=0.2)


def test_used_dynamic_range_streams_and_measures_the_span():
    rng = np.random.default_rng(1)
    frames = (0.2 + 0.4 * rng.random((32, 32)) for _ in range(5))  # a generator: nothing is collected
    stats = used_dynamic_range(frames)
    assert stats["used_range"] == pytest.approx(0.4 * 0.98, abs=0.01)
    assert stats["occupied_bins"] == pytest.approx(0.4, abs=0.02)
    assert len(stats["histogram"]) == 256


def test_tracked_features_follow_a_shifted_texture_not_unrelated_noise():
    rng = np.random.default_rng(2)
    texture = cv2.GaussianBlur(rng.random((160, 200)).astype(np.float32), (0, 0), 1.5)
    texture = (texture - texture.min()) / (texture.max() - texture.min())
    shifted = np.roll(texture, (3, 5), axis=(0, 1))
    unrelated = cv2.GaussianBlur(rng.random((160, 200)).astype(np.float32), (0, 0), 1.5)
    unrelated = (unrelated - unrelated.min()) / (unrelated.max() - unrelated.min())
    same, other = tracked_features([texture, shifted, unrelated])
    assert same > 100 and other < same / 5


def test_inverse_lut_gain_is_one_over_the_slope():
    from thermal_wild_ns.analysis.diagnostics import gain_summary, inverse_lut_gain

    levels = np.arange(1000, dtype=np.float64)
    lut = np.where(levels < 500, levels, 500 + 0.25 * (levels - 500))  # rare top levels squeezed 4x
    frame = np.array([[100, 200], [700, 900]])
    np.testing.assert_allclose(inverse_lut_gain(lut, frame), [[1.0, 1.0], [4.0, 4.0]])
    summary = gain_summary([inverse_lut_gain(lut, frame)], [frame.astype(float)], hottest=0.25)
    assert summary["median_hottest"] == pytest.approx(4.0) and summary["hottest_over_4x"] == 0.0
    assert summary["median"] == pytest.approx(2.5)


def test_error_amplification_known_answers():
    from thermal_wild_ns.analysis.diagnostics import error_amplification

    raw = [np.linspace(0.0, 1.0, 40000).reshape(200, 200)]
    # a LUT that stretches 2x: errors halve when mapped back; the identity leaves them as they are
    halved = error_amplification([2 * r for r in raw], raw, lambda p, t: p / 2, sigma=0.01)
    same = error_amplification(raw, raw, lambda p, t: p, sigma=0.01)
    assert halved["rms"] == pytest.approx(0.5, rel=0.02) and same["rms"] == pytest.approx(1.0, rel=0.02)
    assert same["p99"] == pytest.approx(2.576, rel=0.05)  # |N(0, 1)|'s 99th percentile
    # squeezing the hottest levels 4x (a rare band, as equalization does) grows their errors 4x
    squeeze = lambda p, t: np.where(p < 0.9, p, 0.9 + 4 * (p - 0.9))  # noqa: E731
    hot = error_amplification(
        [np.where(r < 0.9, r, 0.9 + (r - 0.9) / 4) for r in raw], raw, squeeze, sigma=0.001, hottest=0.05
    )
    assert hot["rms_hottest"] == pytest.approx(4.0, rel=0.05) and hot["rms"] < 2.0


def test_diagnose_command_on_the_demo_scene(demo_scene_dir, tmp_path):
    from thermal_wild_ns.analysis.diagnose import DiagnoseArgs, diagnose

    result = diagnose(DiagnoseArgs(data=demo_scene_dir, output_dir=tmp_path / "out", cache_dir=tmp_path / "cache"))
    written = json.loads((tmp_path / "out" / "diagnostics.json").read_text())
    assert written["frames"] == 40 and written["layout"] == "nerfstudio"
    for side in ("before", "after"):
        assert len(written[side]["delta_i"]) == 40 and len(written[side]["tracked_features"]) == 39
    # the demo scene's injected drift is reduced, and BBHE widens the used range
    assert written["after"]["std_delta_i"] < written["before"]["std_delta_i"]
    assert written["after"]["dynamic_range"]["used_range"] > written["before"]["dynamic_range"]["used_range"]
    assert result["summary"].startswith(demo_scene_dir.name + ": std dI_t")
    gain = written["inverse_lut_gain"]
    assert gain["median"] > 0 and gain["median_hottest"] > 0 and 0.0 <= gain["hottest_over_4x"] <= 1.0
    assert (
        written["error_amplification"]["rms"] > 0 and written["preprocessing"]["equalization_strength"] == 0.5
    )  # the default
    # the demo's frames drift by level offsets, with gains within a few percent: the full method trains raw
    assert written["advice"].startswith("`wild-thermal` trains on the raw frames")
    assert "would still train on its raw frames: the frames differ by level offsets" in written["advice"]


def test_diagnose_finds_a_stable_capture_that_the_full_method_trains_raw(tmp_path):
    from thermal_wild_ns.analysis.diagnose import DiagnoseArgs, diagnose
    from thermal_wild_ns.data.demo_scene import generate_demo_scene, stress_scene_config

    scene = generate_demo_scene(tmp_path / "clean", stress_scene_config("clean", path_views=0))
    frame = json.loads((scene / "transforms.json").read_text())["frames"][5]["file_path"]
    image = cv2.imread(str(scene / frame), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(scene / frame), np.zeros_like(image))  # a dead read-out among the frames
    result = diagnose(
        DiagnoseArgs(data=scene, output_dir=tmp_path / "out", cache_dir=tmp_path / "cache", spectrum_frames=4)
    )
    assert result["after"]["std_delta_i"] > result["before"]["std_delta_i"]
    assert result["advice"].startswith("`wild-thermal` trains on the raw frames")
    assert "would still train on its raw frames: the capture is stable" in result["advice"]
    assert result["degenerate_frames"] == [Path(frame).name] and result["frames"] == 39  # listed, left out
    for png in ("diagnostics.png", "frames.png"):
        image = cv2.imread(str(tmp_path / "out" / png))
        assert image is not None and image.shape[0] > 100


def test_diagnose_never_advises_the_preprocessing_a_drone_survey_loses_by(tmp_path):
    """flight2's frames vary in level and contrast, so the contrast rule would preprocess them if asked; the full
    method trains them raw, which scored higher on both real captures: the line says the default first and the
    rule's answer as what happens if asked, not as advice to ask."""
    from thermal_wild_ns.analysis.diagnose import DiagnoseArgs, diagnose

    if not FLIGHT2.is_dir():
        pytest.skip(f"flight2 not found at {FLIGHT2} (it sits in ../shared beside the checkout)")
    result = diagnose(
        DiagnoseArgs(data=FLIGHT2, output_dir=tmp_path / "out", cache_dir=tmp_path / "cache", spectrum_frames=4)
    )
    assert result["advice"].startswith("`wild-thermal` trains on the raw frames")
    assert "would preprocess this capture: the frames' levels and contrast vary" in result["advice"]


def test_preprocessing_stage_names_a_frame_with_nans(tmp_path):
    from thermal_wild_ns.data.capture import ThermalFrame
    from thermal_wild_ns.data.thermal_io import RadiometricRange
    from thermal_wild_ns.preprocessing.photometric import PhotometricConfig
    from thermal_wild_ns.preprocessing.stage import preprocess

    good, bad = np.full((8, 8), 21.0, np.float32), np.full((8, 8), 22.0, np.float32)
    bad[2, 3] = np.nan
    np.save(tmp_path / "a.npy", good)
    np.save(tmp_path / "b.npy", bad)
    frames = [ThermalFrame(tmp_path / n, np.eye(4), 10, 10, 4, 4, 8, 8) for n in ("a.npy", "b.npy")]
    with pytest.raises(ValueError, match=r"b\.npy: non-finite pixel values"):
        preprocess(frames, RadiometricRange(20.0, 25.0, "float32"), PhotometricConfig(), tmp_path / "cache")
    assert list((tmp_path / "cache").iterdir()) == []  # nothing half-written
