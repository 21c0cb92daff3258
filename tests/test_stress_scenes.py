"""The stress scenes: every fault is really there, and nothing else changes."""

import json

import cv2
import numpy as np
import pytest

from thermal_wild_ns.data.demo_scene import COUNTS_RANGE, STRESS_FAULTS, generate_demo_scene, stress_scene_config

FAULTS = ["clean", *STRESS_FAULTS.keys() - {"clean"}, "all"]


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    root = tmp_path_factory.mktemp("stress")
    return {fault: generate_demo_scene(root / fault, stress_scene_config(fault, path_views=6)) for fault in FAULTS}


def frames(scene, folder="images"):
    return [
        cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.float64)
        for p in sorted((scene / folder).glob("frame_*.png"))
    ]


def test_clean_scene_is_its_own_ground_truth(scenes):
    assert all(np.array_equal(a, b) for a, b in zip(frames(scenes["clean"]), frames(scenes["clean"], "ground_truth")))


def test_every_scene_shows_the_same_content(scenes):
    truth = frames(scenes["clean"], "ground_truth")
    for fault in ("outlier", "drift", "ffc", "vignetting", "fixed-pattern"):
        assert all(np.array_equal(a, b) for a, b in zip(frames(scenes[fault], "ground_truth"), truth)), fault


def test_outlier_frame_is_30_percent_brighter(scenes):
    low, high = COUNTS_RANGE
    normalised = lambda scene: [(f - low) / (high - low) for f in frames(scene)]  # noqa: E731  (the model's scale)
    observed, clean = normalised(scenes["outlier"]), normalised(scenes["clean"])
    ratios = [o.mean() / c.mean() for o, c in zip(observed, clean)]
    assert ratios[13] == pytest.approx(1.3, abs=1e-3)
    assert all(r == pytest.approx(1.0, abs=1e-3) for i, r in enumerate(ratios) if i != 13)
    # a bright frame, not a saturated one: only its hottest pixels leave the recording range
    assert 0.0 < (observed[13] > 1.0).mean() < 0.05 and (clean[13] > 1.0).mean() == 0.0


def test_drift_and_flat_field_sawtooth(scenes):
    clean = frames(scenes["clean"])
    drift = [o.mean() - c.mean() for o, c in zip(frames(scenes["drift"]), clean)]
    assert drift[-1] - drift[0] > 150  # 200 counts of offset drift (+10 % gain) over the sequence
    ffc = np.array([o.mean() - c.mean() for o, c in zip(frames(scenes["ffc"]), clean)])
    np.testing.assert_allclose(ffc[:18], 15.0 * np.arange(18), atol=0.6)  # climbs 15 counts per frame ...
    assert ffc[18] == pytest.approx(0.0, abs=0.6)  # ... and drops back every 18 frames


def test_vignetting_falls_off_toward_the_corners(scenes):
    observed, clean = frames(scenes["vignetting"])[5], frames(scenes["clean"])[5]
    ratio = (observed - 3000.0) / (clean - 3000.0)
    assert ratio[48, 64] == pytest.approx(1.0, abs=0.02)
    assert ratio[0, 0] == pytest.approx(0.65, abs=0.03) and ratio[-1, -1] == pytest.approx(0.65, abs=0.03)


def test_fixed_pattern_noise_is_fixed_and_has_rows_and_columns(scenes):
    diffs = [o - c for o, c in zip(frames(scenes["fixed-pattern"]), frames(scenes["clean"]))]
    assert np.allclose(diffs[0], diffs[20], atol=1.0)  # the same pattern in every frame
    assert np.std(diffs[0].mean(axis=0)) > 3.0 and np.std(diffs[0].mean(axis=1)) > 3.0


def test_low_contrast_and_large_sky(scenes):
    clean, low = frames(scenes["clean"]), frames(scenes["low-contrast"])
    assert np.std(low[5]) == pytest.approx(0.15 * np.std(clean[5]), rel=0.05)
    sky = lambda scene: np.mean([np.isinf(np.load(p)).mean() for p in sorted((scene / "depth").glob("*.npy"))])  # noqa: E731
    assert sky(scenes["sky"]) > 0.4 > sky(scenes["clean"])


def test_path_views_are_clean_and_lie_between_training_views(scenes):
    meta = json.loads((scenes["all"] / "transforms.json").read_text())
    path = meta["path"]
    assert len(path) == 6 and path[0]["frame"] == 0.0 and path[-1]["frame"] == 39.0
    assert all(0 < p["frame"] % 1 or p["frame"] in (0.0, 39.0) for p in path)  # between frames, not on them
    for p in path:
        assert (scenes["all"] / p["file_path"]).is_file() and (scenes["all"] / p["depth_npy_path"]).is_file()
    with pytest.raises(ValueError, match="unknown stress fault 'rain'"):
        stress_scene_config("rain")


def test_view_dependent_radiance_changes_with_the_view_angle():
    """`stress:view`: a surface seen head-on keeps its temperature, seen at a grazing angle it moves
    toward the sky it reflects (emissivity 1 - 0.5 (1 - cos)^2); the sky itself is unchanged."""
    from thermal_wild_ns.data.demo_scene import _ground_temp, _sky_temp, cast_rays

    origin = np.array([[0.0, 0.0, 5.0], [0.0, -5.0, 1e-3]])  # above a ground point, and level with it
    target = np.array([0.0, 0.0, 0.0])
    dirs = (target - origin) / np.linalg.norm(target - origin, axis=-1, keepdims=True)
    plain, _, _ = cast_rays(origin, dirs)
    viewed, _, _ = cast_rays(origin, dirs, view_falloff=0.5)
    truth = _ground_temp(np.zeros(1), np.zeros(1))[0]
    assert plain == pytest.approx([truth, truth]) and viewed[0] == pytest.approx(truth)  # head-on: unchanged
    reflected_sky = _sky_temp(np.array([0.0, 1.0, 0.0]))  # the grazing view reflects the horizon
    assert viewed[1] == pytest.approx(0.5 * truth + 0.5 * reflected_sky, abs=0.05)
    up = np.array([[0.0, 0.0, 1.0]])
    assert cast_rays(np.zeros((1, 3)) + [0, 0, 1], up, 0.5)[0] == pytest.approx(_sky_temp(up))
