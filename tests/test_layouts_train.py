"""Every registered dataparser, end to end, as a new user runs it: `ns-train wild-thermal <parser>
--data FIXTURE` with the method's own defaults (the coarse-to-fine warm-up and the automatic stop
included), parsed by nerfstudio's own command line, for a few steps: far shorter than the warm-up,
as a user's first quick try is. Each run must end with its final checkpoint after the automatic
stop's held-back score, then `ns-eval` scores it and `wild-thermal-render` renders from it.

The layout tests (test_data_layouts.py) check poses and splits; this checks that training, the stop
rule, the evaluation and the renders consume what the readers give (a COLMAP reader's float64
intrinsics once crashed every COLMAP layout at step 0; the stop's score once crashed every run that
ended inside the warm-up)."""

from __future__ import annotations

import json
import math

import layout_fixtures as fx
import pytest
from ns_runs import STEPS, check_run_end_to_end, ns_train, run_args
from real_data import FLIGHT2

pytestmark = pytest.mark.slow  # trains through nerfstudio: minutes on a CPU

FRAMES = 26
"""Enough frames for the automatic stop to hold two training frames back (it needs 20)."""

SCALE = {"msx-data": 0.125, "ye-thermal-data": 0.25, "metashape-data": 0.125, "exif-gps-data": 0.125}

# registered parser -> (fixture writer, folder name); 'thermal' detects the layout itself
PARSERS = {
    "thermal": (lambda root: fx.write_colmap(root, n=FRAMES), "scene"),
    "thermal-nerfstudio-data": (lambda root: fx.write_nerfstudio(root, n=FRAMES), "scene"),
    "thermalnerf-data": (lambda root: fx.write_thermalnerf(root, n=FRAMES), "scene"),
    "ye-thermal-data": (lambda root: fx.write_ye(root, n=FRAMES), "seq01"),
    "msx-data": (lambda root: fx.write_msx(root, n=FRAMES), "scene"),
    "thermalmix-data": (lambda root: fx.write_thermalmix(root, n=FRAMES), "lion"),
    "mvtv-data": (lambda root: fx.write_llff(root, n=FRAMES, folder="thermal"), "scene"),
    "llff-thermal-data": (lambda root: fx.write_llff(root, n=FRAMES), "scene"),
    "thermal-colmap-data": (lambda root: fx.write_colmap(root, n=FRAMES), "scene"),
    "ti-nsd-data": (lambda root: fx.write_ti_nsd(root, n=FRAMES), "scene"),
    "thermal-demo-data": (None, "scene"),
    "odm-data": (lambda root: fx.write_odm(root, n=FRAMES), "survey"),
    # a real drone survey as the drone wrote it: radiometric JPEGs + the Metashape alignment
    "metashape-data": (lambda root: root.symlink_to(FLIGHT2, target_is_directory=True), "flight2"),
    # the same survey with no photogrammetry: SfM from the frames' GPS and gimbal priors
    "exif-gps-data": (lambda root: root.symlink_to(FLIGHT2, target_is_directory=True), "flight2"),
}
SITE = {"metashape-data": 2056, "exif-gps-data": 32632}
"""Where flight2's exports land: Metashape's project CRS (LV95), else the UTM zone of the site (32N)."""


def test_every_registered_parser_has_a_case():
    from nerfstudio.plugins.registry_dataparser import discover_dataparsers

    ours = {
        name for name, spec in discover_dataparsers()[0].items() if type(spec).__module__.startswith("thermal_wild_ns")
    }
    assert ours == set(PARSERS)


@pytest.mark.parametrize("parser", sorted(PARSERS))
def test_parser_trains_scores_evaluates_and_renders(parser, tmp_path):
    writer, folder = PARSERS[parser]
    root = tmp_path / "data" / folder
    root.parent.mkdir(parents=True, exist_ok=True)
    if writer is not None:
        writer(root)
    out = tmp_path / "out"
    # the layouts of larger frames (MSX 640x480, Ye 382x288) train at the size of the others (about 64x48),
    # through the datamanager's resolution option: on a CPU their evaluation would otherwise take minutes
    scale = ["--pipeline.datamanager.camera-res-scale-factor", str(SCALE.get(parser, 1.0))]
    config = ns_train(
        [*run_args(out, STEPS, *scale), parser, "--data", str(root), "--cache-dir", str(tmp_path / "seeds")]
    )
    assert config.pipeline.model.num_downscales > 0  # the warm-up was on: the run ended inside it
    layout = config.pipeline.datamanager.dataparser.layout
    assert layout == ("auto" if parser == "thermal" else layout)
    results = check_run_end_to_end(out / "x" / "wild-thermal" / "run", tmp_path)
    if parser in SITE:  # a calibrated camera: ns-eval scores in °C too; the run knows where it is
        assert all(math.isfinite(results[f"celsius_{m}_time"]) for m in ("mae", "rmse", "p95"))
        record = json.loads((out / "x" / "wild-thermal" / "run" / "data.json").read_text())
        assert 46.3 < record["georeference"]["latitude"] < 46.5
        assert ("2056" in (record["georeference"]["crs_wkt"] or "")) == (parser == "metashape-data")
        check_survey_exports(out / "x" / "wild-thermal" / "run" / "config.yml", tmp_path, SITE[parser])


def check_survey_exports(config, tmp_path, epsg: int):
    """A °C point cloud and a °C orthomosaic where the site is (in the CRS `epsg`), from a run of a
    few steps: every Gaussian and every covered pixel (its Gaussians are not yet opaque)."""
    import numpy as np
    import rasterio
    from plyfile import PlyData
    from rasterio.warp import transform

    from thermal_wild_ns.export.survey import ExportCelsiusPoints, ExportOrthomosaic

    # the site's centre (flight2's mean GPS position) in that CRS, and the survey's extent around it
    (east,), (north,) = transform("EPSG:4326", f"EPSG:{epsg}", [6.2390], [46.3972])
    ExportCelsiusPoints(config, tmp_path / "points.ply", min_opacity=0.0).main()
    points = PlyData.read(str(tmp_path / "points.ply"))["vertex"].data
    assert len(points) > 1000 and np.isfinite(points["value"]).all()
    assert abs(np.median(points["x"]) - east) < 150 and abs(np.median(points["y"]) - north) < 150
    ExportOrthomosaic(config, tmp_path / "ortho.tif", ground_resolution=1.0, min_coverage=0.0).main()
    with rasterio.open(tmp_path / "ortho.tif") as raster:
        celsius, height = raster.read(1), raster.read(2)
        assert raster.crs.to_epsg() == epsg and raster.count == 2 and abs(raster.transform.a - 1.0) < 0.01
        # tiled, deflate with the floating-point predictor (as survey tools write their rasters)
        assert raster.block_shapes == [(256, 256)] * 2 and raster.tags(ns="IMAGE_STRUCTURE")["PREDICTOR"] == "3"
        assert east - 250 < raster.bounds.left < raster.bounds.right < east + 250
    assert np.isfinite(celsius).mean() > 0.5 and -20 < np.nanmedian(celsius) < 60
    assert np.nanmedian(height) < 400  # below the cameras (~400 m above the ellipsoid); 3 steps shape no ground yet
