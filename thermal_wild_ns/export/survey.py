"""What a survey is for: `wild-thermal-export celsius-points` (the model's Gaussians as a °C point
cloud) and `wild-thermal-export orthomosaic` (a °C orthomosaic GeoTIFF), both where the site is.

A run trained on a georeferenced capture (the `metashape` layout) records where its world frame
sits on the Earth (`RUN/data.json`: a local east-north-up frame in metres, its origin and the
project's coordinate system). nerfstudio then moved and scaled that frame into the model's
(`dataparser_transform`, `dataparser_scale`); `world_from_model` undoes it, and `SurveyFrame`
takes local coordinates to the project's CRS through rasterio (GDAL/PROJ).

The orthomosaic is rendered by the model itself at the canonical photometric state: one sensor
state for every pixel, so no seams where one frame's footprint meets the next (a mosaic of the
raw frames shows each frame's drift there). The camera is a nadir pinhole far above the site
(`ORTHO_DISTANCE` times its size) with its image axes on the CRS's grid: the parallax of the
site's relief is its height over that factor (4 m of relief: under 10 cm at the edges).
Temperatures are the camera's own calibration where it has one (radiometric JPEGs), the
dataset's documented bounds otherwise; without either, native units, and the file says which.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Tuple

import numpy as np
import torch
from nerfstudio.cameras.cameras import Cameras, CameraType
from nerfstudio.utils.eval_utils import eval_setup
from plyfile import PlyData, PlyElement

from thermal_wild_ns.data.georeference import Georeference
from thermal_wild_ns.errors import InputError
from thermal_wild_ns.export.gaussian_splat import canonical_emission
from thermal_wild_ns.pipeline.photometric_state import canonical_state, render_layers
from thermal_wild_ns.pipeline.run_check import check_trained_run, write_atomically
from thermal_wild_ns.pipeline.thermal_pipeline import DATA_RECORD

ORTHO_DISTANCE = 50.0
"""The orthomosaic's camera stands this many site sizes above the ground."""


def world_from_model(pipeline) -> np.ndarray:
    """[4, 4]: the model's frame -> the capture's world frame (undoes nerfstudio's orientation,
    centring and scale of the poses)."""
    outputs = pipeline.datamanager.train_dataparser_outputs
    model_from_world = np.eye(4)
    model_from_world[:3, :4] = outputs.dataparser_transform.cpu().numpy()
    model_from_world[:3] *= float(outputs.dataparser_scale)
    return np.linalg.inv(model_from_world)


def run_georeference(load_config: Path) -> Optional[Georeference]:
    """The georeference the run recorded at training (None: a capture with no place on the Earth)."""

    record = Path(load_config).parent / DATA_RECORD
    found = json.loads(record.read_text()).get("georeference") if record.is_file() else None
    if found is None:
        return None
    return Georeference(tuple(found["origin_ecef"]), found["crs_wkt"], found.get("source", ""))


class SurveyFrame:
    """Local east-north-up metres -> the project's CRS (easting, northing, ellipsoidal height)."""

    def __init__(self, georeference: Georeference):
        # rasterio (GDAL, PROJ) where a survey has a georeference: a capture without one exports without it
        from rasterio.crs import CRS

        self.georeference = georeference
        # no project CRS (OpenDroneMap gives a GPS origin only): the site's UTM zone, metres like a project's
        zone = int((georeference.longitude + 180) // 6) % 60 + 1
        self.crs = CRS.from_epsg((32600 if georeference.latitude >= 0 else 32700) + zone)
        if georeference.crs_wkt:
            # by its EPSG code where the WKT names one: PROJ builds its own, tested definition (Metashape's
            # WKT of LV95, with its own parameter names, has no inverse in PROJ)
            self.crs = CRS.from_wkt(georeference.crs_wkt)
            code = self.crs.to_epsg(confidence_threshold=20)  # its AUTHORITY["EPSG", ...] is honoured at 20
            if code is not None:
                self.crs = CRS.from_epsg(code)
        self.ecef_from_local = np.linalg.inv(georeference.ecef_to_local())

    def to_crs(self, xyz: np.ndarray) -> np.ndarray:
        """[N, 3] local -> [N, 3] CRS coordinates (float64)."""
        from rasterio.warp import transform

        ecef = xyz @ self.ecef_from_local[:3, :3].T + self.ecef_from_local[:3, 3]  # [N, 3]
        x, y, z = transform("EPSG:4978", self.crs, ecef[:, 0], ecef[:, 1], ecef[:, 2])
        return np.stack([x, y, z], axis=1)

    def grid_axes(self, at: np.ndarray) -> Tuple[np.ndarray, float]:
        """The local direction [3] of the CRS's easting axis at `at` (the grid convergence), and the
        CRS units per local metre along it (the projection's scale)."""
        step = 10.0
        crs = self.to_crs(np.stack([at, at + [step, 0.0, 0.0], at + [0.0, step, 0.0]]))
        jacobian = np.stack([crs[1, :2] - crs[0, :2], crs[2, :2] - crs[0, :2]], axis=1) / step  # d(E,N)/d(e,n)
        east = np.linalg.solve(jacobian, [1.0, 0.0])
        scale = 1.0 / float(np.linalg.norm(east))
        return np.array([*(east * scale), 0.0]), scale


def celsius_or_native(rng, original: np.ndarray) -> Tuple[np.ndarray, str]:
    """Dataset-normalised values -> (°C, 'celsius') where the capture converts, else (native, units)."""
    if rng.has_celsius:
        return rng.to_celsius(original).astype(np.float32), "celsius"
    return rng.to_native(original).astype(np.float32), f"native {rng.dtype} levels (no temperature calibration)"


def _load(load_config: Path):
    check_trained_run(load_config)
    _, pipeline, _, _ = eval_setup(Path(load_config), test_mode="inference")
    return pipeline


# ------------------------------------------------------------------ °C point cloud
@dataclass
class ExportCelsiusPoints:
    """The model's Gaussians as a point cloud with their temperature, in the survey's CRS."""

    load_config: Path
    """The run's config.yml."""
    output_path: Path = Path("celsius_points.ply")
    """The PLY to write."""
    min_opacity: float = 0.5
    """Gaussians less opaque than this are left out (faint floaters)."""

    def main(self) -> dict:
        pipeline = _load(self.load_config)
        rng = pipeline.datamanager.train_dataset.thermal_range
        model = pipeline.model
        world = world_from_model(pipeline)
        means = model.means.detach().cpu().numpy().astype(np.float64)  # [N, 3] model frame
        local = means @ world[:3, :3].T + world[:3, 3]  # [N, 3] capture frame
        opacity = torch.sigmoid(model.opacities.detach()).cpu().numpy()[:, 0]  # [N]
        values, units = celsius_or_native(rng, canonical_emission(pipeline))
        keep = (opacity >= self.min_opacity) & np.isfinite(values)
        georeference = run_georeference(self.load_config)
        survey = SurveyFrame(georeference) if georeference else None
        xyz = survey.to_crs(local[keep]) if survey else local[keep]
        vertices = np.empty(int(keep.sum()), dtype=[(n, "f8") for n in "xyz"] + [("value", "f4"), ("opacity", "f4")])
        vertices["x"], vertices["y"], vertices["z"] = xyz.T
        vertices["value"], vertices["opacity"] = values[keep], opacity[keep]
        frame = (
            f"{survey.crs.to_string()} (easting, northing, ellipsoidal height)"
            if survey
            else "the capture's own frame (not georeferenced)"
        )
        comments = [f"thermal_wild_ns value: {units}", f"thermal_wild_ns coordinates: {frame}"]
        ply = PlyData([PlyElement.describe(vertices, "vertex")], comments=comments)
        write_atomically(Path(self.output_path), lambda tmp: ply.write(str(tmp)))
        print(f"{self.output_path}: {len(vertices)} points ({units}), coordinates in {frame[:60]}")
        return {"points": len(vertices), "units": units, "georeferenced": georeference is not None}


# ------------------------------------------------------------------ orthomosaic
@dataclass
class ExportOrthomosaic:
    """A °C orthomosaic GeoTIFF of a nadir survey, rendered by the model at the canonical state."""

    load_config: Path
    """The run's config.yml (a georeferenced capture: the metashape layout)."""
    output_path: Path = Path("orthomosaic_celsius.tif")
    """The GeoTIFF to write: band 1 the temperature, band 2 the surface's height (float32, NaN where no
    Gaussian covers the ground)."""
    ground_resolution: Optional[float] = None
    """Metres per pixel (default: the training frames' own ground sampling at their median height)."""
    min_coverage: float = 0.5
    """Pixels the Gaussians cover less than this are left empty (the background model is not ground)."""
    max_pixels: int = 8192
    """Largest side of the raster; a finer resolution over a large site stops with what would fit."""

    def main(self) -> dict:
        georeference = run_georeference(self.load_config)
        if georeference is None:
            raise InputError(
                f"{self.load_config}: this run's capture has no georeference (its layout gives none; the "
                f"metashape layout does): an orthomosaic would have no place on the map"
            )
        pipeline = _load(self.load_config)
        survey = SurveyFrame(georeference)
        model, rng = pipeline.model, pipeline.datamanager.train_dataset.thermal_range
        world = world_from_model(pipeline)
        model_from_world = np.linalg.inv(world)
        means = model.means.detach().cpu().numpy().astype(np.float64) @ world[:3, :3].T + world[:3, 3]  # [N, 3]
        # the site: where the Gaussians that may cover a pixel are (as opaque as --min-coverage asks)
        solid = means[torch.sigmoid(model.opacities.detach()).cpu().numpy()[:, 0] >= self.min_coverage]
        if len(solid) < 10:
            raise InputError(f"{self.load_config}: the model has almost no opaque Gaussians: nothing to map")
        low, high = np.percentile(solid[:, :2], 1, axis=0), np.percentile(solid[:, :2], 99, axis=0)
        ground = float(np.median(solid[:, 2]))
        centre = np.array([*(low + high) / 2, ground])
        east, crs_per_metre = survey.grid_axes(centre)
        north = np.cross([0.0, 0.0, 1.0], east)
        along = np.abs((solid[:, :2] - centre[:2]) @ np.stack([east[:2], north[:2]], axis=1))  # [N, 2] grid metres
        half_e, half_n = np.percentile(along[:, 0], 99), np.percentile(along[:, 1], 99)
        gsd = self.ground_resolution or self._training_gsd(pipeline, world, ground)
        width, rows = int(math.ceil(2 * half_e / gsd)), int(math.ceil(2 * half_n / gsd))
        if max(width, rows) > self.max_pixels:
            raise InputError(
                f"{self.load_config}: {width}x{rows} pixels at {gsd:.3f} m: over --max-pixels {self.max_pixels}; "
                f"use --ground-resolution {2 * max(half_e, half_n) / self.max_pixels:.3f} or coarser"
            )
        distance = ORTHO_DISTANCE * 2 * max(half_e, half_n)
        down = np.array([0.0, 0.0, -1.0])
        c2w = np.eye(4)  # OpenCV axes: x = the grid's east, y = its south (image rows run north to south), z down
        c2w[:3, :3] = np.stack([east, np.cross(down, east), down], axis=1)
        c2w[:3, 3] = centre + [0.0, 0.0, distance]
        in_model = model_from_world @ c2w
        in_model[:3, :3] /= np.cbrt(np.linalg.det(in_model[:3, :3]))  # rotation only; the scale is in the position
        in_model = in_model @ np.diag([1.0, -1.0, -1.0, 1.0])  # nerfstudio's (OpenGL) camera axes
        focal = float(distance / gsd)  # a Python float: numpy's float64 would make gsplat's projection mix dtypes
        camera = Cameras(
            camera_to_worlds=torch.from_numpy(in_model[None, :3, :4]).float(),
            fx=focal,
            fy=focal,
            cx=width / 2.0,
            cy=rows / 2.0,
            width=width,
            height=rows,
            camera_type=CameraType.PERSPECTIVE,
        ).to(model.device)
        state = canonical_state(pipeline)
        layers = render_layers(pipeline, camera, state)
        values, units = celsius_or_native(rng, layers["original"])
        # the surface's height: the camera's, less the rendered depth (model units back to metres);
        # local up is the ellipsoid's normal at the origin (off by (d / 2R) * d over d metres: negligible)
        height = c2w[2, 3] - layers["depth"] / np.cbrt(np.linalg.det(model_from_world[:3, :3])) + georeference.height
        empty = layers["coverage"] < self.min_coverage
        values[empty] = np.nan
        height = height.astype(np.float32)
        height[empty] = np.nan
        corner = survey.to_crs((centre - half_e * east + half_n * north)[None])[0]  # the raster's top-left
        pixel = gsd * crs_per_metre
        import rasterio
        from rasterio.transform import Affine

        # tiled, deflate with the floating-point predictor: as survey tools write their rasters (GIS software reads
        # a window without the whole width; the predictor makes float rasters smaller, losslessly)
        profile = dict(
            driver="GTiff", width=width, height=rows, count=2, dtype="float32", nodata=float("nan"),
            crs=survey.crs, transform=Affine(pixel, 0.0, corner[0], 0.0, -pixel, corner[1]), compress="deflate",
            predictor=3, tiled=True, blockxsize=256, blockysize=256,
        )  # fmt: skip

        def write(tmp: Path) -> None:
            with rasterio.open(tmp, "w", **profile) as raster:
                raster.write(values, 1)
                raster.write(height, 2)
                raster.set_band_description(1, f"temperature ({units})")
                raster.set_band_description(2, "surface height (m above the WGS84 ellipsoid)")
                raster.update_tags(
                    units=units, photometric_state=state.label, rendered_by="thermal_wild_ns (canonical state)"
                )

        write_atomically(Path(self.output_path), write)
        covered = np.isfinite(values)
        print(
            f"{self.output_path}: {width}x{rows} at {gsd:.3f} m, {units}, {covered.mean():.0%} of it mapped, "
            f"{np.nanmin(values):.2f}..{np.nanmax(values):.2f}"
        )
        return {"width": width, "height": rows, "gsd": gsd, "units": units, "covered": float(covered.mean())}

    @staticmethod
    def _training_gsd(pipeline, world: np.ndarray, ground: float) -> float:
        """The training frames' own ground sampling: median height above the ground over focal length."""
        cameras = pipeline.datamanager.train_dataset.cameras
        centres = cameras.camera_to_worlds[:, :3, 3].cpu().numpy().astype(np.float64) @ world[:3, :3].T + world[:3, 3]
        return float(np.median((centres[:, 2] - ground) / cameras.fx[:, 0].cpu().numpy()))
