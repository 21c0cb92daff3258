"""Stability measures give known answers on constructed cases."""

import numpy as np
import pytest

from thermal_wild_ns.analysis.stability import (
    background_error,
    error_exceedance,
    flicker,
    floater_fraction,
    visible_floater_fraction,
)


def _scene():
    depth = np.full((20, 30), 5.0)
    depth[:5] = np.inf  # sky in the top rows
    return depth


def test_a_perfect_render_has_no_floaters_and_no_excess_flicker():
    true_depth = _scene()
    alpha = np.where(np.isfinite(true_depth), 1.0, 0.0)
    assert floater_fraction(np.where(np.isfinite(true_depth), true_depth, 0.0), alpha, true_depth) == 0.0
    rng = np.random.default_rng(0)
    gts = [rng.random((20, 30)) + 0.01 * t for t in range(6)]
    assert flicker(gts, gts) == {"mean_excess": 0.0, "pixel_excess": 0.0}
    assert error_exceedance(gts[0], gts[0]) == 0.0 and background_error(gts[0], gts[0], true_depth) == 0.0


def test_floaters_in_front_of_the_surface_and_against_the_sky_are_counted():
    true_depth = _scene()
    depth = np.where(np.isfinite(true_depth), true_depth, 0.0)
    alpha = np.where(np.isfinite(true_depth), 1.0, 0.0)
    depth[10:12, 0:10] = 2.0  # a floater at 2 m in front of the 5 m surface: 20 pixels
    alpha[0:2, 0:10] = 0.9  # something opaque against the sky: 20 pixels
    assert floater_fraction(depth, alpha, true_depth) == pytest.approx(40 / 600)
    depth[10:12, 0:10] = 4.8  # within 10 % of the surface: not a floater
    assert floater_fraction(depth, alpha, true_depth) == pytest.approx(20 / 600)


def test_visible_floaters_are_the_floaters_with_an_error():
    true_depth = _scene()
    depth = np.where(np.isfinite(true_depth), true_depth, 0.0)
    alpha = np.where(np.isfinite(true_depth), 1.0, 0.0)
    depth[10:12, 0:10] = 2.0  # 20 floater pixels
    alpha[0:2, 0:10] = 0.9  # 20 pixels of sky painted by Gaussians
    gt = np.full((20, 30), 0.5)
    pred = gt.copy()
    assert floater_fraction(depth, alpha, true_depth) == pytest.approx(40 / 600)
    assert visible_floater_fraction(depth, alpha, true_depth, pred, gt) == 0.0  # right colour: not seen
    pred[10:12, 0:5] += 0.3  # half the surface floater shows
    pred[15:17, 0:10] += 0.3  # an error where nothing floats: not a floater
    assert visible_floater_fraction(depth, alpha, true_depth, pred, gt) == pytest.approx(10 / 600)


def test_flicker_measures_only_what_the_truth_does_not_do():
    rng = np.random.default_rng(1)
    gts = [rng.random((20, 30)) * 0.1 + 0.5 for _ in range(8)]
    jitter = [0.0, 0.05, 0.0, 0.05, 0.0, 0.05, 0.0, 0.05]
    preds = [g + j for g, j in zip(gts, jitter)]  # the render's brightness jumps by 0.05 every frame
    result = flicker(preds, gts)
    assert result["pixel_excess"] > 0.02 and result["mean_excess"] > 0.03
    with pytest.raises(ValueError, match="two or more renders"):
        flicker(preds[:1], gts[:1])


def test_background_error_looks_at_the_sky_only():
    true_depth = _scene()
    gt = np.zeros((20, 30))
    pred = gt.copy()
    pred[10:] = 1.0  # wrong on the surface only
    assert background_error(pred, gt, true_depth) == 0.0
    pred[:5] = 0.2  # now the sky too
    assert background_error(pred, gt, true_depth) == pytest.approx(0.2)
    assert error_exceedance(pred, gt, 0.5) == pytest.approx(10 / 20)
