"""Drone surveys as the drone and the photogrammetry left them: the frames (radiometric JPEGs or 16-bit
frames, the visible photos beside them left out: `survey_frames.py`) beside a Metashape alignment, an
OpenDroneMap / OpenSfM reconstruction, or nothing but the frames' GPS (placed by structure from motion). Each
reader returns a `ThermalCapture` in a local east-north-up frame in metres, every 8th frame held out, with each
frame's °C calibration at its own measurement settings or the user's (`settings`)."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Optional

from thermal_wild_ns.data.capture import SeedPoints, ThermalCapture, ThermalFrame, interval_split
from thermal_wild_ns.data.celsius import FILE_SETTINGS, MeasurementSettings
from thermal_wild_ns.data.exif import focal_length_px, read_frame_prior, survey_georeference
from thermal_wild_ns.data.exif_sfm import cached_structure_from_motion
from thermal_wild_ns.data.frame_files import natural_key
from thermal_wild_ns.data.metashape import read_lens_calibration, read_metashape_xml
from thermal_wild_ns.data.opensfm import read_reconstruction
from thermal_wild_ns.data.survey_frames import survey_celsius, survey_frames
from thermal_wild_ns.data.thermal_io import frame_size
from thermal_wild_ns.errors import InputError, MissingInput

METASHAPE_FOLDERS = ("", "metashape")
"""Where a Metashape XML is looked for, relative to the data folder."""


def _metashape_xml(root: Path) -> Optional[Path]:
    """The Metashape XML in `root` or `root/metashape` (a chunk's doc.xml or exported cameras)."""
    for folder in METASHAPE_FOLDERS:
        for path in sorted((root / folder).glob("*.xml")):
            with open(path, "rb") as handle:
                head = handle.read(4096)
            if b"<chunk" in head or b"<document" in head:
                return path
    return None


def _survey_capture(
    layout: str,
    root: Path,
    source: Path,
    posed: list,
    unaligned=(),
    settings: MeasurementSettings = FILE_SETTINGS,
    **facts,
) -> ThermalCapture:
    """A drone survey's capture from its photogrammetry: `posed`, (name, ThermalFrame with no image
    yet) per aligned camera, matched by file name to the survey's thermal frames (`survey_frames`); frames
    in file-name order, which is capture order for drone files (DJI_0001, ...); every 8th held out.
    Radiometric JPEGs must carry their thermal data (never their colour preview); each frame's °C at its
    own measurement settings or `settings`. `facts`: the capture's georeference and points."""

    found = survey_frames(root)
    folder, images = found.folder, {p.stem: p for p in found.thermal}
    frames = []
    for name, frame in sorted(posed, key=lambda named: natural_key(named[0])):
        image = images.get(Path(name).stem)
        if image is None:
            continue
        frame.image = image
        frames.append(frame)
    if not frames:
        raise InputError(
            f"{source}: none of its {len(posed)} aligned cameras has a thermal frame in {folder} "
            f"(cameras are matched to files by name, e.g. {posed[0][0] if posed else '-'})"
        )
    without = sorted(set(images) - {Path(name).stem for name, _ in posed})
    if without:
        not_aligned = [name for name in without if name in {Path(u).stem for u in unaligned}]
        warnings.warn(
            f"{folder}: {len(without)} frame(s) without a pose in {source.name} are left out"
            f"{' (the photogrammetry could not align ' + ', '.join(not_aligned[:5]) + ')' if not_aligned else ''}: "
            f"{', '.join(without[:5])}{' ...' if len(without) > 5 else ''}",
            stacklevel=3,
        )
    for frame, split in zip(frames, interval_split(len(frames))):
        frame.split = split
    reference, per_frame = survey_celsius([f.image for f in frames], folder, settings)
    for frame, calibration in zip(frames, per_frame):
        frame.celsius = calibration
    return ThermalCapture(layout, root, frames, "every 8th frame held out", celsius_calibration=reference, **facts)


def read_metashape(root: Path, settings: MeasurementSettings = FILE_SETTINGS) -> ThermalCapture:
    """A drone survey aligned in Agisoft Metashape: its XML (`METASHAPE_FOLDERS` says where it is
    looked for) and the frames as the camera wrote them (radiometric JPEGs, or 16-bit frames) in
    the first of `FRAME_FOLDERS` that holds images. Poses in a local east-north-up frame in metres
    where the chunk is georeferenced (`metashape.py`)."""

    xml = _metashape_xml(root)
    if xml is None:
        raise MissingInput(f"{root}: no Metashape XML in {' or '.join(str(root / f) for f in METASHAPE_FOLDERS)}")
    posed, georeference, unaligned = read_metashape_xml(xml)
    return _survey_capture("metashape", root, xml, posed, unaligned, settings, georeference=georeference)


OPENSFM_FILES = ("opensfm/reconstruction.json", "reconstruction.json")
"""Where an OpenDroneMap project (opensfm/) or an OpenSfM dataset keeps its reconstruction."""


def read_odm(root: Path, settings: MeasurementSettings = FILE_SETTINGS) -> ThermalCapture:
    """A drone survey reconstructed by OpenDroneMap or OpenSfM (`opensfm.py`): the reconstruction's
    shots, cameras and points in its east-north-up frame around `reference_lla`, and the frames as
    the camera wrote them in the first of `FRAME_FOLDERS` that holds images (ODM: `images/`)."""

    path = next((root / f for f in OPENSFM_FILES if (root / f).is_file()), None)
    if path is None:
        raise MissingInput(f"{root}: no {' or '.join(OPENSFM_FILES)}")
    posed, xyz, georeference = read_reconstruction(path)
    points = SeedPoints(xyz, "opensfm") if xyz is not None and len(xyz) else None
    return _survey_capture("odm", root, path, posed, (), settings, georeference=georeference, points=points)


def read_exif_gps(
    root: Path,
    cache_root: Optional[Path] = None,
    lens_calibration: Optional[Path] = None,
    settings: MeasurementSettings = FILE_SETTINGS,
) -> ThermalCapture:
    """A drone survey with no photogrammetry: geotagged frames as the camera wrote them (the first
    of `FRAME_FOLDERS` that holds images), placed by structure from motion with their EXIF GPS and
    XMP gimbal angles as priors (`exif_sfm.py`; cached under `cache_root`, default
    `<root>/.thermal_wild_ns`). `lens_calibration`: a Metashape / Agisoft Lens calibration XML,
    held fixed (without it the focal length comes from the files and distortion is taken as none).
    Frames without GPS are left out by name."""

    found = survey_frames(root)
    folder, images = found.folder, list(found.thermal)
    read = [(p, read_frame_prior(p)) for p in images]
    geotagged, priors = [p for p, prior in read if prior is not None], [prior for _, prior in read if prior is not None]
    if not geotagged:
        raise InputError(f"{folder}: none of its {len(images)} frames has a GPS position in its EXIF")
    if len(geotagged) < len(images):
        missing = [p.name for p, prior in read if prior is None]
        warnings.warn(
            f"{folder}: {len(missing)} frame(s) without GPS are left out: {', '.join(missing[:5])}", stacklevel=2
        )
    width, height = frame_size(geotagged[0])  # SfM checks that every frame has this size
    focal = focal_length_px(geotagged[0], width, height)  # one camera: its first frame says it
    georeference = survey_georeference(
        priors, f"EXIF GPS of {folder} (altitudes above sea level, taken as ellipsoidal heights)"
    )
    calibration = read_lens_calibration(Path(lens_calibration)) if lens_calibration is not None else None
    result = cached_structure_from_motion(
        geotagged,
        priors,
        georeference,
        focal,
        calibration,
        Path(cache_root) if cache_root else root / ".thermal_wild_ns",
    )
    camera = result.camera
    posed = [
        (
            name,
            ThermalFrame(
                Path(), pose, camera.fx, camera.fy, camera.cx, camera.cy, width, height, camera.distortion.copy()
            ),
        )
        for name, pose in result.poses.items()
    ]
    unaligned = [p.name for p in geotagged if p.name not in result.poses]
    points = SeedPoints(result.points, "sfm (exif-gps)") if len(result.points) else None
    facts = dict(georeference=georeference, points=points)
    return _survey_capture("exif-gps", root, folder, posed, unaligned, settings, **facts)


def exif_gps_mismatch(root: Path) -> Optional[str]:
    try:
        first = survey_frames(root).thermal[0]
        if read_frame_prior(first) is None:
            return f"{first.name} has no GPS position in its EXIF"
    except InputError as err:  # no frames, or an unreadable first one: not this layout
        return str(err)
    return None


def metashape_mismatch(root: Path) -> Optional[str]:
    if _metashape_xml(root) is None:
        return "no Metashape XML (with a <chunk>) in the folder or metashape/"
    return None
