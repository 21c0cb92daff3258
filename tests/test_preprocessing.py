"""Photometric stabilization + BBHE: properties of the LUTs, the cached stage, the datamanager."""

import itertools
from pathlib import Path

import numpy as np
import pytest

from experiments.sensor_drift import frame_offsets
from thermal_wild_ns.analysis.diagnostics import relative_mean_change
from thermal_wild_ns.preprocessing.photometric import (
    VARIANTS,
    LevelGrid,
    PhotometricConfig,
    apply_lut,
    blend_inverses,
    blend_luts,
    frame_luts,
    invert_lut,
)

GRID16 = LevelGrid(65536)


def drifting_sequence(num_frames=60, seed=0):
    """A static scene seen through a known gain (+8 %) and offset (+80 counts) ramp, plus noise."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:96, 0:128]
    base = 3500 + 300 * (0.5 + 0.5 * np.sin(u / 9.0) * np.cos(v / 7.0))
    frames = []
    for t in range(num_frames):
        gain, offset = 1 + 0.08 * t / num_frames, 80 * t / num_frames
        frames.append(
            np.clip(np.round(3000 + (base - 3000) * gain + offset + rng.normal(0, 2, base.shape)), 0, 65535).astype(
                np.uint16
            )
        )
    return frames


def skewed_frames(num=5, seed=1):
    """Low-contrast uint16 frames with a long tail and empty levels (as thermal frames are)."""
    rng = np.random.default_rng(seed)
    return [
        (3600 + rng.gamma(2.0, 40.0, (48, 64)) + 300 * (rng.random((48, 64)) < 0.01)).astype(np.uint16)
        for _ in range(num)
    ]


@pytest.mark.parametrize("variant", VARIANTS)
def test_luts_strictly_monotonic_and_invertible_within_a_level(variant):
    frames = skewed_frames()
    for lut, frame in zip(frame_luts(frames, GRID16, 3550.0, 4100.0, PhotometricConfig(variant)), frames):
        assert lut.shape == (65536,) and np.all(np.isfinite(lut))
        assert np.all(np.diff(lut) > 0)  # strictly: the inverse exists
        processed = apply_lut(lut, frame, GRID16)  # float32, as the stage stores it
        back = invert_lut(lut, processed.astype(np.float64), GRID16)
        assert np.abs(back - frame).max() <= 1.0
        every_level = invert_lut(lut, lut, GRID16)  # the whole LUT, not only the levels present
        assert np.abs(every_level - np.arange(65536)).max() <= 1e-6


def test_identity_at_beta_zero_without_bbhe():
    frames = skewed_frames()
    for lut in frame_luts(frames, GRID16, 3550.0, 4100.0, PhotometricConfig("stab", alpha=0.3, beta=0.0)):
        np.testing.assert_array_equal(lut, np.arange(65536, dtype=np.float64))


def test_equalization_strength_blends_bbhe_with_its_input():
    frames = skewed_frames()
    luts = lambda **kw: list(frame_luts(frames, GRID16, 3550.0, 4100.0, PhotometricConfig("stab+bbhe", **kw)))  # noqa: E731
    stab_only = list(frame_luts(frames, GRID16, 3550.0, 4100.0, PhotometricConfig("stab")))
    for none, stab in zip(luts(equalization_strength=0.0), stab_only):
        np.testing.assert_array_equal(none, stab)
    for full, half, stab, frame in zip(
        luts(equalization_strength=1.0), luts(equalization_strength=0.5), stab_only, frames
    ):
        # half-way between at the frame's levels, but a few that strictly_increasing lifted past long
        # stretches of empty levels (0.05 of a level per empty level)
        occupied = np.unique(frame)
        off = np.abs(half[occupied] - 0.5 * (full[occupied] + stab[occupied]))
        assert np.mean(off <= 1e-6) > 0.9 and off.max() < 5.0
        assert np.all(np.diff(half) > 0)
    with pytest.raises(ValueError, match="equalization_strength must be in"):
        PhotometricConfig(equalization_strength=1.5)


def _std_delta_i(frames):
    return float(np.std(relative_mean_change([f.mean() for f in frames])))


def test_stabilization_removes_injected_drift():
    frames = drifting_sequence()
    raw = _std_delta_i(frames)

    def stabilized(alpha, beta):
        luts = frame_luts(frames, GRID16, 3400.0, 3900.0, PhotometricConfig("stab", alpha, beta))
        return _std_delta_i([apply_lut(lut, f, GRID16) for lut, f in zip(luts, frames)])

    # measured: defaults (alpha 0.01, beta 0.5) 0.0103 -> 0.0065 (1.58x); beta 1: -> 0.0027 (3.8x)
    assert raw / stabilized(0.01, 0.5) >= 1.5
    assert raw / stabilized(0.01, 1.0) >= 3.5


def test_bbhe_preserves_mean_brightness_plain_equalization_does_not():
    """BBHE (Kim 1997; full strength) keeps the output mean near the input mean: within half the distance from the
    input mean to the middle of the range, plus 2 % of the range. Plain equalization moves it to the middle."""
    low, high = 3550.0, 4100.0
    middle = (low + high) / 2
    frames = skewed_frames(num=8, seed=3)
    bbhe = frame_luts(frames, GRID16, low, high, PhotometricConfig("bbhe", equalization_strength=1.0))
    histeq = frame_luts(frames, GRID16, low, high, PhotometricConfig("histeq", equalization_strength=1.0))
    for frame, lut_b, lut_h in zip(frames, bbhe, histeq):
        mean_in = frame.mean()
        mean_bbhe = apply_lut(lut_b, frame, GRID16).mean()
        mean_he = apply_lut(lut_h, frame, GRID16).mean()
        assert abs(mean_bbhe - mean_in) <= 0.5 * abs(middle - mean_in) + 0.02 * (high - low)
        assert abs(mean_bbhe - mean_in) < abs(mean_he - mean_in)
        # and it does enhance: the processed frame spreads over more of the range
        assert np.percentile(apply_lut(lut_b, frame, GRID16), 99) - np.percentile(
            apply_lut(lut_b, frame, GRID16), 1
        ) > 1.5 * (np.percentile(frame, 99) - np.percentile(frame, 1))


def test_streaming_reads_one_frame_per_lut():
    consumed = []

    def frames():
        for i, frame in enumerate(itertools.cycle(skewed_frames(2))):
            consumed.append(i)
            yield frame

    stream = frame_luts(frames(), GRID16, 3550.0, 4100.0, PhotometricConfig())
    for _ in range(3):
        next(stream)
    assert len(consumed) == 3  # an endless sequence is fine: nothing is collected


def test_degenerate_frames_are_safe_or_refused():
    constant = np.full((10, 10), 3700, np.uint16)
    (lut,) = frame_luts([constant], GRID16, 3550.0, 4100.0, PhotometricConfig())  # a single, constant frame
    assert np.all(np.diff(lut) > 0) and abs(invert_lut(lut, lut[3700:3701], GRID16)[0] - 3700) < 1e-6
    sizes = [np.full((5, 7), 3600, np.uint16), skewed_frames(1)[0]]  # different sizes: histograms are normalised
    assert len(list(frame_luts(sizes, GRID16, 3550.0, 4100.0, PhotometricConfig()))) == 2
    nan = np.full((4, 4), 20.0, np.float32)
    nan[1, 1] = np.nan
    grid = LevelGrid.for_dtype("float32", 10.0, 30.0)
    with pytest.raises(ValueError, match="frame 0 has non-finite values"):
        list(frame_luts([nan], grid, 10.0, 30.0, PhotometricConfig()))
    with pytest.raises(ValueError, match="unknown preprocessing variant"):
        PhotometricConfig("clahe")


def test_float_temperatures_round_trip_on_the_16bit_grid():
    rng = np.random.default_rng(5)
    temps = [20.0 + 10.0 * rng.random((30, 40)).astype(np.float32) for _ in range(3)]
    grid = LevelGrid.for_dtype("float32", 20.0, 30.0)
    for lut, frame in zip(frame_luts(temps, grid, 20.0, 30.0, PhotometricConfig()), temps):
        assert np.abs(grid.values(grid.levels(frame)) - frame).max() <= 0.5 * grid.step * (1 + 1e-6)  # nearest level
        half_level = 0.5 * grid.step * (1 + 1e-6)
        back = invert_lut(lut, lut[grid.levels(frame)], grid)
        assert np.abs(back - frame).max() <= half_level  # the LUT itself loses nothing but the rounding to a level
        stored = invert_lut(lut, apply_lut(lut, frame, grid).astype(np.float64), grid)
        # processed frames are stored as float32, whose rounding can move a value across part of a
        # sparsely filled level (rise MIN_LUT_RISE): still well inside one level
        assert np.abs(stored - frame).max() <= 2 * half_level


# --------------------------------------------------------------------------- the cached stage
def _demo_sequence(demo_scene_dir):
    from thermal_wild_ns.data.dataparsers import ThermalDataParserConfig

    parser = ThermalDataParserConfig(data=demo_scene_dir, layout="nerfstudio").setup()
    return parser.capture().frames, parser.radiometric_range()


def test_stage_caches_and_rebuilds_when_parameters_change(demo_scene_dir, tmp_path, monkeypatch):
    import thermal_wild_ns.preprocessing.stage as stage

    frames, rng = _demo_sequence(demo_scene_dir)
    first = stage.preprocess(frames, rng, PhotometricConfig(), tmp_path)
    assert first.luts.shape == (40, 65536) and len(list((first.folder / "frames").glob("*.npy"))) == 40
    processed = np.load(first.frame_path(3))
    assert processed.dtype == np.float32 and len(np.unique(processed)) > 256  # no 8-bit re-quantisation
    raw = rng.read(frames[3].image)
    np.testing.assert_allclose(
        first.to_original_normalised(processed, first.lut(3)), raw, atol=1.0 / (rng.high - rng.low)
    )
    # and forward again: the training-space value of a raw frame at a state
    np.testing.assert_allclose(first.to_processed_normalised(raw, first.lut(3)), processed, atol=1e-5)

    monkeypatch.setattr(stage, "frame_luts", lambda *a, **k: (_ for _ in ()).throw(AssertionError("recomputed")))
    assert stage.preprocess(frames, rng, PhotometricConfig(), tmp_path).folder == first.folder  # from the cache
    with pytest.raises(AssertionError, match="recomputed"):  # new parameters: rebuilt ...
        stage.preprocess(frames, rng, PhotometricConfig(alpha=0.2), tmp_path)
    # ... and the failed rebuild left nothing half-written
    assert sorted(p.name for p in tmp_path.iterdir()) == [first.folder.name]


def test_datamanager_applies_the_variant_and_exposes_frame_indices(demo_scene_dir, tmp_path):
    from thermal_wild_ns.data.dataparsers import ThermalDataParserConfig
    from thermal_wild_ns.pipeline.datamanager import ThermalDatamanagerConfig

    images = {}
    for variant in ("none", "stab+bbhe"):
        config = ThermalDatamanagerConfig(
            dataparser=ThermalDataParserConfig(data=demo_scene_dir, layout="nerfstudio"),
            preprocessing=PhotometricConfig(variant),
            preprocessing_cache=tmp_path,
        )
        datamanager = config.setup(device="cpu")
        data = datamanager.train_dataset.get_data(0)
        assert int(data["frame_index"]) == 1  # frame 0 is held out (every 8th)
        images[variant] = data["image"]
        assert (datamanager.preprocessed is None) == (variant == "none")
    assert images["none"].shape == images["stab+bbhe"].shape == (96, 128, 1)
    # BBHE spreads the frame over the range: the processed frame has more contrast
    assert float(images["stab+bbhe"].std()) > 1.3 * float(images["none"].std())


def test_the_full_method_preprocesses_a_capture_whose_contrast_varies_and_trains_the_others_raw(
    demo_scene_dir, tmp_path
):
    from thermal_wild_ns.data.dataparsers import ThermalDataParserConfig
    from thermal_wild_ns.data.demo_scene import DemoSceneConfig, generate_demo_scene, stress_scene_config
    from thermal_wild_ns.pipeline.datamanager import ThermalDatamanagerConfig
    from thermal_wild_ns.preprocessing.stage import (
        CONTRAST_QUANTILES,
        frame_contrast_spread,
        frame_mean_spread,
        preprocessing_pays,
    )

    assert frame_mean_spread([0.2, 0.4]) == pytest.approx(0.14826)  # the MAD, scaled to a std
    assert frame_mean_spread([0.3] * 9 + [0.9]) == 0.0  # one outlier frame does not make a capture unsteady
    q = CONTRAST_QUANTILES
    assert frame_contrast_spread([q, q + 0.2, q - 0.1]) == pytest.approx(0.0)  # offsets: no contrast change
    gains = [1.0, 1.2, 0.8, 1.1, 5.0]
    assert frame_contrast_spread([g * q + 0.1 for g in gains]) == pytest.approx(  # log gains' MAD, one outlier
        1.4826 * np.median(np.abs(np.log(gains) - np.median(np.log(gains)))), rel=1e-6
    )
    assert preprocessing_pays(0.02, 0.01, 0.2) and not preprocessing_pays(0.02, 0.01, 0.1)
    assert not preprocessing_pays(0.01, 0.01, 0.2) and not preprocessing_pays(0.01, 0.02, 0.2)
    stable = generate_demo_scene(tmp_path / "clean", stress_scene_config("clean", path_views=0))
    # the demo's content, each frame at a gain drawn about 1 +- 0.35, as an automatic gain control makes it
    agc = generate_demo_scene(tmp_path / "agc", DemoSceneConfig(jitter_gain=0.35, jitter_counts=0.0, drift_counts=0.0))

    def datamanager(scene, skip_when_stable):
        return ThermalDatamanagerConfig(
            dataparser=ThermalDataParserConfig(data=scene, layout="nerfstudio"),
            preprocessing=PhotometricConfig(skip_when_stable=skip_when_stable),
            preprocessing_cache=tmp_path / "cache",
        ).setup(device="cpu")

    varying = datamanager(agc, True)
    assert varying.preprocessed is not None and varying.preprocessing_used.startswith("stab+bbhe: the frames' levels")
    assert varying.preprocessed.frame_contrast_spread() > 0.15
    offsets = datamanager(demo_scene_dir, True)  # the demo's drift: offsets, gains within a few percent
    assert offsets.preprocessed is None and offsets.preprocessing_used.startswith("none: the frames differ by level")
    kept = datamanager(stable, False)  # the fixed preprocessing of the ablations
    raw, processed = kept.preprocessed.frame_mean_spreads()
    assert processed >= raw  # equalization moves the clean frames' levels apart
    skipped = datamanager(stable, True)
    assert skipped.preprocessed is None and skipped.preprocessing_used.startswith("none: the capture is stable")
    # one frame 30 % brighter does not make the clean capture unsteady
    outlier = generate_demo_scene(tmp_path / "outlier", stress_scene_config("outlier", path_views=0))
    assert datamanager(outlier, True).preprocessed is None
    np.testing.assert_array_equal(  # trains on the frames as captured
        skipped.train_dataset.get_data(0)["image"][..., 0].numpy(), skipped.train_dataset.original_image(0)
    )
    # the decision does not change what is processed: one cache per capture
    assert len([p for p in (tmp_path / "cache").iterdir() if p.name.startswith("preprocessed-")]) == 4


def test_novel_views_map_back_through_the_median_lut_which_one_outlier_frame_cannot_move(tmp_path):
    """The canonical LUT for views no frame was captured at (paths, viewer, exports). On the outlier
    stress scene (the clean scene plus one frame at +30 % gain), mapping the clean scene's processed
    path views back through the outlier scene's training LUTs: the level-wise median gives back the
    truth, the mean (used before) caps the path at about 36 dB by itself (under 30 dB on the
    saturated outlier frame of generator version 2)."""
    import json

    from thermal_wild_ns.data.dataparsers import ThermalDemoDataParserConfig
    from thermal_wild_ns.preprocessing.photometric import invert_lut
    from thermal_wild_ns.preprocessing.stage import preprocess

    def scene(fault):
        parser = ThermalDemoDataParserConfig(data=tmp_path / fault, scene=fault).setup()
        frames = list(parser.get_dataparser_outputs("train").metadata["frame_indices"])
        # full-strength BBHE, where one frame moves the mean LUT most (at half strength the mean's
        # path PSNR is 47.8 dB)
        config = PhotometricConfig(equalization_strength=1.0)
        train = [i in frames for i in range(len(parser.capture().frames))]
        return (
            parser,
            preprocess(parser.capture().frames, parser.radiometric_range(), config, tmp_path / "cache", train=train),
            frames,
        )

    clean_parser, clean, frames = scene("clean")
    _, outlier, outlier_frames = scene("outlier")
    assert frames == outlier_frames
    rng, grid = clean_parser.radiometric_range(), clean.grid
    median = outlier.median_lut()
    assert np.all(np.diff(median) > 0)  # still invertible
    np.testing.assert_array_equal(median, np.median(np.asarray(outlier.luts)[frames], axis=0))

    path = json.loads((tmp_path / "clean" / "transforms.json").read_text())["path"][::6]
    truth = np.stack([rng.read(tmp_path / "clean" / view["file_path"]) for view in path])  # normalised original
    processed = np.interp(rng.to_native(truth), grid.values(np.arange(grid.num_levels)), clean.median_lut())

    def psnr(lut):
        return -10 * np.log10(np.mean((rng.normalize(invert_lut(lut, processed, grid)) - truth) ** 2))

    assert psnr(median) > 45.0  # 46.6 when written
    assert psnr(np.asarray(outlier.luts)[frames].mean(axis=0)) < 40.0  # 36.5: the one bright frame moves the mean


# --------------------------------------------------------------------------- photometric state in time
def test_time_weights_give_a_training_frames_own_state_and_interpolate_between():
    from thermal_wild_ns.preprocessing.photometric import time_weights

    times = [1.0, 3.0, 7.0]
    assert time_weights(times, 3.0) == (1, 1, 0.0)  # a training frame: exactly its own
    assert time_weights(times, 2.0) == (0, 1, 0.5)
    assert time_weights(times, 6.0) == (1, 2, 0.75)
    assert time_weights(times, 0.0) == (0, 0, 0.0) and time_weights(times, 9.5) == (
        2,
        2,
        0.0,
    )  # nearest, no extrapolation
    with pytest.raises(ValueError, match="strictly increasing"):
        time_weights([3.0, 1.0], 2.0)


def test_interpolated_luts_are_strictly_increasing_and_exact_at_training_frames(demo_scene_dir, tmp_path):
    from thermal_wild_ns.data.dataparsers import ThermalDataParserConfig
    from thermal_wild_ns.preprocessing.stage import preprocess

    parser = ThermalDataParserConfig(data=demo_scene_dir, layout="nerfstudio").setup()
    frames = parser.capture().frames
    train = [f.split == "train" for f in frames]
    sequence = preprocess(
        frames, parser.radiometric_range(), PhotometricConfig(equalization_strength=1.0), tmp_path, train=train
    )
    held_out = [t for t, is_train in enumerate(train) if not is_train]
    assert sequence.train_indices == [t for t, is_train in enumerate(train) if is_train]
    for t in held_out[1:]:  # frame 0 lies before every training frame
        lut = sequence.lut_at(t)
        assert np.all(np.diff(lut) > 0)
        # every 8th is held out: midway between its neighbours' maps, their inverses averaged
        np.testing.assert_allclose(lut, blend_luts(sequence.lut(t - 1), sequence.lut(t + 1), 0.5))
        for fraction in (0.25, 0.9):
            assert np.all(np.diff(sequence.lut_at(t - 1 + fraction)) > 0)
        with pytest.raises(KeyError, match="held out"):  # its own LUT is the oracle's, never a state
            sequence.lut(t)
        assert not np.array_equal(sequence.oracle_lut(t), lut)
    for t in sequence.train_indices[:5]:
        np.testing.assert_array_equal(sequence.lut_at(t), sequence.lut(t))
        np.testing.assert_array_equal(sequence.lut_at(float(t)), np.asarray(sequence.luts[t]))


def test_held_out_frames_never_change_training_or_the_predicted_renders(tmp_path):
    """Multiply a held-out frame by 2, or fill it with noise: every training frame's processed
    pixels, the radiometric range and the seeds stay bit-identical, and so do the trained model's
    `novel` and `time` renders of that view after a short training run."""
    import shutil

    import cv2
    import torch

    from thermal_wild_ns.data.dataparsers import ThermalDataParserConfig
    from thermal_wild_ns.data.demo_scene import generate_demo_scene
    from thermal_wild_ns.demo import demo_trainer_config
    from thermal_wild_ns.pipeline.photometric_state import canonical_state, render, state_at

    original = generate_demo_scene(tmp_path / "scene")
    held_out = Path("images") / "frame_00008.png"  # every 8th frame is held out
    variants = {}
    for name, change in (
        ("same", None),
        ("double", lambda f: (f.astype(np.uint32) * 2).clip(0, 65535).astype(np.uint16)),
        ("noise", lambda f: np.random.default_rng(0).integers(0, 65535, f.shape, dtype=np.uint16)),
    ):
        root = tmp_path / name
        shutil.copytree(original, root, ignore=shutil.ignore_patterns(".thermal_wild_ns"))
        if change is not None:
            frame = cv2.imread(str(root / held_out), cv2.IMREAD_UNCHANGED)
            assert frame is not None and frame.dtype == np.uint16
            cv2.imwrite(str(root / held_out), change(frame))
        config = demo_trainer_config(tmp_path / f"run-{name}", steps=20, max_gaussians=2000)
        config.pipeline.datamanager.dataparser = ThermalDataParserConfig(
            data=root, layout="nerfstudio", seed_points="random", num_random_points=300
        )
        config.pipeline.datamanager.preprocessing = PhotometricConfig()  # on, whatever the rule decides
        torch.manual_seed(0)
        trainer = config.setup(local_rank=0, world_size=1)
        trainer.setup()
        trainer.train()
        pipeline = trainer.pipeline
        datamanager = pipeline.datamanager
        sequence = datamanager.preprocessed
        view = list(datamanager.eval_dataset.metadata["frame_indices"]).index(8)
        camera, _ = datamanager.fixed_indices_eval_dataloader[view]
        variants[name] = (
            datamanager.dataparser.radiometric_range(),
            {t: sequence.read_frame(t) for t in sequence.train_indices},
            np.asarray(sequence.luts[sequence.train_indices]),
            datamanager.train_dataparser_outputs.metadata["points3D_xyz"],
            render(pipeline, camera, canonical_state(pipeline))[1],
            render(pipeline, camera, state_at(pipeline, 8))[1],
        )
    same = variants["same"]
    for name in ("double", "noise"):
        rng, frames, luts, seeds, novel, timed = variants[name]
        assert rng == same[0], name
        assert frames.keys() == same[1].keys() and all(np.array_equal(frames[t], same[1][t]) for t in frames), name
        np.testing.assert_array_equal(luts, same[2])
        assert torch.equal(seeds, same[3])
        np.testing.assert_array_equal(novel, same[4])
        np.testing.assert_array_equal(timed, same[5])


def test_the_preprocessing_rule_report_names_each_scenes_measurements_and_decision(tmp_path):
    from experiments.preprocessing_rule import RuleArgs, main

    rows = main(RuleArgs(scenes=("demo",), output=tmp_path / "rule.md", work_dir=tmp_path))
    (row,) = rows
    assert not row["pays"] and row["processed_spread"] < row["raw_spread"]
    assert 0 < row["contrast_spread"] < 0.15  # offsets only
    table = (tmp_path / "rule.md").read_text()
    cells = f"{row['raw_spread']:.4f} -> {row['processed_spread']:.4f} | {row['contrast_spread']:.3f}"
    assert f"| demo | {cells} | no |" in table


def test_a_blend_of_two_drifted_frames_luts_is_the_in_between_frames_lut():
    """Frame b is frame a drifted by 100 levels (b(x) = a(x - 100)); a weight w of the way between
    them is the frame drifted by 100 w: the inverses blend, the outputs level by level would not
    (a's curvature makes their average another map)."""
    levels = np.arange(1000, dtype=np.float64)

    def frame_lut(x):
        return x + 50.0 * np.sin(x / 100.0)  # strictly increasing, curved

    a, b = frame_lut(levels), frame_lut(levels - 100.0)
    blended = blend_luts(a, b, 0.3)
    inside = slice(150, 850)  # where both frames' inverses are defined
    assert np.allclose(blended[inside], frame_lut(levels - 30.0)[inside], atol=1e-6)
    assert not np.allclose((0.7 * a + 0.3 * b)[inside], frame_lut(levels - 30.0)[inside], atol=1.0)


def test_a_blend_of_increasing_luts_is_increasing_and_exact_at_its_ends():
    rng = np.random.default_rng(0)
    for _ in range(20):
        a, b = (np.cumsum(rng.random(256) + 1e-3) * rng.uniform(0.5, 2) + rng.uniform(-50, 50) for _ in range(2))
        for w in (0.1, 0.5, 0.9):
            assert np.all(np.diff(blend_luts(a, b, w)) > 0)
        assert blend_luts(a, b, 0.0) is a and blend_luts(a, b, 1.0) is b
    with pytest.raises(ValueError, match="blend weight"):
        blend_luts(a, b, 1.5)


def test_the_mean_of_drifted_frames_inverses_is_the_mean_drift_and_of_two_frames_their_blend():
    """Three frames drifted by 0, 60 and 150 levels: the LUT whose inverse is their inverses' mean
    (`blend_inverses` at equal weights) is the frame drifted by their mean, 70; of two frames it is
    `blend_luts` at w = 0.5; strictly increasing."""
    levels = np.arange(1000, dtype=np.float64)

    def frame_lut(x):
        return x + 50.0 * np.sin(x / 100.0)

    luts = [frame_lut(levels - d) for d in (0.0, 60.0, 150.0)]
    mean = blend_inverses(luts, [1.0 / 3] * 3)
    inside = slice(200, 800)
    assert np.allclose(mean[inside], frame_lut(levels - 70.0)[inside], atol=1e-6)
    assert np.allclose(blend_inverses(luts[:2], [0.5, 0.5]), blend_luts(luts[0], luts[1], 0.5), atol=1e-9)
    assert np.all(np.diff(mean) > 0)


def test_frame_offsets_recover_a_drifting_level_and_hold_a_fixed_gradient_as_a_level_along_the_way():
    """Survey-like observations: 300 scene points, 12 frames, each point crossing the frame from top to
    bottom as the frames go by and back (a drone's lanes). A level drift alone comes back exactly. A
    fixed gradient down the sensor alone (no drift) comes back as offsets proportional to each frame's
    place along the lane: from the points alone the two are the same thing (`frame_offsets`)."""
    rng = np.random.default_rng(0)
    frames, points = 12, 300
    scene = rng.uniform(0.2, 0.8, points)
    track = np.concatenate([np.arange(6), np.arange(5, -1, -1)]).astype(float)  # down the lane and back
    y = (track[:, None] - rng.uniform(0, 5, points)[None]) / 6.0  # [F, P] each point's height in the frame
    inside = np.abs(y) <= 0.5

    drift = rng.normal(0.0, 0.03, frames)
    offsets, kept = frame_offsets(np.where(inside, scene[None] + drift[:, None], np.nan))
    assert len(kept) == frames
    np.testing.assert_allclose(offsets, drift - np.median(drift), atol=1e-6)

    gradient = 0.1  # per frame height
    offsets, _ = frame_offsets(np.where(inside, scene[None] + gradient * y, np.nan))
    along = gradient * track / 6.0
    np.testing.assert_allclose(offsets, along - np.median(along), atol=1e-6)
