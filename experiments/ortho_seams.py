"""Seams of a survey's orthomosaic: the model's (one photometric state) against a plain mosaic of the
raw frames (each frame's own drift), on the same grid, the same poses and the same surface.

    python -m experiments.ortho_seams --ortho ORTHO.tif --load-config RUN/config.yml --output-dir DIR

The model's orthomosaic (`wild-thermal-export orthomosaic`) gives, per pixel, the surface's position
(its CRS coordinates and band 2's height). Each frame of the capture sees some of those points: its
°C there is its raw counts through the camera's calibration, sampled where the point projects
(OpenCV's projection with the frame's pose and distortion). The plain mosaic takes each pixel from
the frame that sees it nearest its image centre (the usual "nearest nadir" mosaic), which
partitions the map into footprints.

Two measures:
- overlap: for each pair of frames seeing the same pixels, the median |°C difference| between them
  there (what the sensor's drift does to the same ground);
- seams: on the footprint boundaries of that partition, the mean |difference| between the two
  pixels either side (one from each footprint), less the same over neighbouring pixel pairs inside
  the footprints (the texture's own gradient): positive where a boundary steps. Computed on both
  mosaics over the same boundaries.
Writes seams.json and side_by_side.png in the output folder.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tyro


@dataclass
class Args:
    ortho: Path
    """The model's orthomosaic (wild-thermal-export orthomosaic)."""
    load_config: Path
    """The run it was rendered from (its capture: frames, poses, calibration, georeference)."""
    output_dir: Path = Path("outputs/ortho_seams")
    min_pixels: int = 500
    """Frame pairs overlapping on fewer pixels are left out of the overlap measure."""


def surface_points(ortho: Path, survey) -> tuple:
    """The ortho's temperature [H, W] and its pixels' surface points in the capture's local frame [H, W, 3]."""
    import rasterio
    from rasterio.warp import transform

    with rasterio.open(ortho) as raster:
        temperature, height = raster.read(1), raster.read(2)
        rows, cols = np.mgrid[0 : raster.height, 0 : raster.width]
        xs, ys = rasterio.transform.xy(raster.transform, rows.ravel(), cols.ravel())
        crs = raster.crs
    ok = np.isfinite(height.ravel())
    lon, lat, h = transform(crs, "EPSG:4979", np.asarray(xs)[ok], np.asarray(ys)[ok], height.ravel()[ok])
    ecef = np.stack(transform("EPSG:4979", "EPSG:4978", lon, lat, h), axis=1)  # [M, 3]
    local = ecef @ survey.georeference.ecef_to_local()[:3, :3].T + survey.georeference.ecef_to_local()[:3, 3]
    points = np.full((height.size, 3), np.nan)
    points[ok] = local
    return temperature, points.reshape(*height.shape, 3)


def bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """image [h, w] at the points uv [N, 2] (x, y; inside the image), bilinearly."""
    x0 = np.clip(np.floor(uv[:, 0]).astype(int), 0, image.shape[1] - 2)
    y0 = np.clip(np.floor(uv[:, 1]).astype(int), 0, image.shape[0] - 2)
    fx, fy = uv[:, 0] - x0, uv[:, 1] - y0
    top = image[y0, x0] * (1 - fx) + image[y0, x0 + 1] * fx
    bottom = image[y0 + 1, x0] * (1 - fx) + image[y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bottom * fy


def frame_samples(frame, calibration, points: np.ndarray):
    """A frame's °C at each surface point [H, W] (NaN where it does not see it) and the point's
    distance from the image centre in pixels [H, W]."""
    import cv2

    from thermal_wild_ns.data.rjpeg import read_rjpeg

    celsius = calibration.celsius(read_rjpeg(frame.image).raw)  # [h, w]
    flat = points.reshape(-1, 3)
    ok = np.isfinite(flat[:, 0])
    w2c = np.linalg.inv(frame.camera_to_world)
    cam = flat[ok] @ w2c[:3, :3].T + w2c[:3, 3]
    k1, k2, k3, k4, p1, p2 = frame.distortion
    K = frame.intrinsics_matrix().copy()
    K[0, 2] -= 0.5  # COLMAP's pixel convention (corner at 0) -> OpenCV's (centre at 0)
    K[1, 2] -= 0.5
    uv, _ = cv2.projectPoints(cam, np.zeros(3), np.zeros(3), K, np.array([k1, k2, p1, p2, k3]))
    uv = uv[:, 0]
    h, w = celsius.shape
    inside = (cam[:, 2] > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
    values = np.full(len(flat), np.nan)
    distance = np.full(len(flat), np.inf)
    at = np.flatnonzero(ok)[inside]
    values[at] = bilinear(celsius, uv[inside])
    distance[at] = np.hypot(uv[inside, 0] - w / 2, uv[inside, 1] - h / 2)
    return values.reshape(points.shape[:2]), distance.reshape(points.shape[:2])


def seam_step(mosaic: np.ndarray, owner: np.ndarray) -> dict:
    """Mean |difference| of horizontally and vertically neighbouring pixels across footprint
    boundaries, inside footprints, and the first less the second."""
    across, inside = [], []
    for a, b, oa, ob in (
        (mosaic[:, :-1], mosaic[:, 1:], owner[:, :-1], owner[:, 1:]),
        (mosaic[:-1], mosaic[1:], owner[:-1], owner[1:]),
    ):
        ok = np.isfinite(a) & np.isfinite(b) & (oa >= 0) & (ob >= 0)
        diff = np.abs(a - b)
        across.append(diff[ok & (oa != ob)])
        inside.append(diff[ok & (oa == ob)])
    across, inside = np.concatenate(across), np.concatenate(inside)
    return {
        "across_boundaries": float(across.mean()),
        "inside_footprints": float(inside.mean()),
        "step": float(across.mean() - inside.mean()),
        "boundary_pairs": int(len(across)),
    }


def main(args: Args) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import yaml

    from thermal_wild_ns.data import surveys
    from thermal_wild_ns.export.survey import SurveyFrame, run_georeference
    from thermal_wild_ns.progress import track

    config = yaml.load(Path(args.load_config).read_text(), Loader=yaml.Loader)
    capture = surveys.read_metashape(Path(config.pipeline.datamanager.dataparser.data))
    survey = SurveyFrame(run_georeference(args.load_config))
    model, points = surface_points(args.ortho, survey)
    samples, distances = [], []
    for frame in track(capture.frames, "Projecting the frames onto the surface"):
        value, distance = frame_samples(frame, capture.celsius_calibration, points)
        samples.append(value)
        distances.append(distance)
    samples, distances = np.stack(samples), np.stack(distances)  # [F, H, W]
    distances[~np.isfinite(samples)] = np.inf
    owner = np.argmin(distances, axis=0)
    owner[~np.isfinite(distances.min(axis=0))] = -1
    plain = np.take_along_axis(samples, np.maximum(owner, 0)[None], axis=0)[0]
    plain[owner < 0] = np.nan
    both = np.isfinite(plain) & np.isfinite(model)
    overlaps = []
    for i in range(len(samples)):
        for j in range(i + 1, len(samples)):
            shared = np.isfinite(samples[i]) & np.isfinite(samples[j]) & both
            if shared.sum() >= args.min_pixels:
                overlaps.append(float(np.median(np.abs(samples[i][shared] - samples[j][shared]))))
    masked_owner = np.where(both, owner, -1)
    result = {
        "pixels_compared": int(both.sum()),
        "frame_pairs": len(overlaps),
        "overlap_median_abs_difference_celsius": {
            "median": float(np.median(overlaps)),
            "p90": float(np.percentile(overlaps, 90)),
        },
        "seams_plain_mosaic": seam_step(np.where(both, plain, np.nan), masked_owner),
        "seams_model": seam_step(np.where(both, model, np.nan), masked_owner),
        "model_minus_plain_celsius": {
            "median": float(np.median((model - plain)[both])),
            "mean_abs": float(np.mean(np.abs(model - plain)[both])),
        },
    }
    args.output_dir.mkdir(parents=True, exist_ok=True)
    (args.output_dir / "seams.json").write_text(json.dumps(result, indent=1))
    low, high = np.nanpercentile(np.where(both, model, np.nan), [1, 99])
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.5), constrained_layout=True)
    plain_step, model_step = result["seams_plain_mosaic"]["step"], result["seams_model"]["step"]
    for ax, image, title in (
        (axes[0], np.where(both, plain, np.nan), f"plain mosaic of the raw frames (seam step {plain_step:.2f} °C)"),
        (axes[1], np.where(both, model, np.nan), f"the model at its canonical state (seam step {model_step:.2f} °C)"),
    ):
        shown = ax.imshow(image, cmap="inferno", vmin=low, vmax=high)
        ax.set_title(title, fontsize=10)
        ax.set_axis_off()
    fig.colorbar(shown, ax=axes, label="°C", shrink=0.8)
    fig.savefig(args.output_dir / "side_by_side.png", dpi=90)
    print(json.dumps(result, indent=1))
    return result


if __name__ == "__main__":
    main(tyro.cli(Args))
