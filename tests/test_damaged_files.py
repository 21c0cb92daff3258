"""Every reader survives damaged input: each real sample file, cut short at 50 points and with 200 bytes flipped one
at a time (seeded), is either read or refused with an `InputError` naming the file, never another exception or a
hang. The files: every radiometric JPEG and colour-mapped frame in ../shared/data, DUNR's TIFF frames, transforms.json
and COLMAP model (text, and as COLMAP writes it in binary), flight2's Metashape chunk and camera calibration, and
an OpenDroneMap reconstruction made in code."""

from __future__ import annotations

import json
import shutil
import signal
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator, Tuple

import numpy as np
import pytest
from real_data import DUNR, FLIGHT2, RGBT_FRAMES, RJPEG_SAMPLES

from thermal_wild_ns.errors import InputError

TRUNCATIONS = 50
FLIPS = 200
SECONDS_PER_FILE = 120
"""A file's every damaged copy is read within this (a reader that hangs fails the test instead)."""

needs_shared = pytest.mark.skipif(not DUNR.is_dir(), reason="../shared/data is not here")


def damaged(data: bytes, seed: int) -> Iterator[Tuple[str, bytes]]:
    """`TRUNCATIONS` cuts (spread over the file, a third of them within its first 4 KB, where headers are) and
    `FLIPS` single bytes flipped to another value, seeded."""
    rng = np.random.default_rng(seed)
    head = min(len(data), 4096)
    cuts = sorted(set(np.linspace(0, len(data) - 1, TRUNCATIONS - TRUNCATIONS // 3, dtype=int).tolist()))
    cuts += sorted(set(rng.integers(0, head, TRUNCATIONS // 3).tolist()) - set(cuts))
    while len(cuts) < TRUNCATIONS:  # a tiny file: every point
        cuts.append(int(rng.integers(0, len(data))))
    for cut in cuts[:TRUNCATIONS]:
        yield f"cut at byte {cut}", data[:cut]
    for at, by in zip(rng.integers(0, len(data), FLIPS).tolist(), rng.integers(1, 256, FLIPS).tolist()):
        flipped = bytearray(data)
        flipped[at] ^= by
        yield f"byte {at} flipped", bytes(flipped)


@contextmanager
def no_hang(seconds: int):
    def hung(*_):
        raise TimeoutError(f"a reader took over {seconds} s: it hangs")

    previous = signal.signal(signal.SIGALRM, hung)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def survives(read: Callable[[], object], target: Path, original: bytes, seed: int) -> int:
    """`read()` of every damaged copy written over `target`: read, or an `InputError` naming `target` (anything
    else fails, with what was done to the file). The count of refusals."""
    refused = 0
    with no_hang(SECONDS_PER_FILE):
        for what, data in damaged(original, seed):
            target.write_bytes(data)
            try:
                read()
            except InputError as err:
                assert str(target) in str(err) or target.name in str(err), f"{target.name}, {what}: {err}"
                refused += 1
            except Exception as err:  # noqa: BLE001 - what the test is about
                pytest.fail(f"{target.name}, {what}: {type(err).__name__}: {err}")
    target.write_bytes(original)
    return refused


def frame_files():
    if not RJPEG_SAMPLES.is_dir():
        return []
    dunr_frames = sorted((DUNR / "images").glob("*.tiff"))[:2]
    flight2 = sorted((FLIGHT2 / "rjpeg").glob("*.jpg"))[:2]
    return sorted(RJPEG_SAMPLES.glob("*.jpg")) + sorted(RGBT_FRAMES.glob("*.jpg")) + dunr_frames + flight2


@needs_shared
@pytest.mark.parametrize("sample", frame_files(), ids=lambda p: p.name)
def test_a_damaged_thermal_frame_is_read_or_refused_naming_it(sample, tmp_path):
    """The frame readers: its raster (`read_raw_frame`, by content) and, for a radiometric JPEG, its records and
    °C through the FLIR formula (DJI's °C is its converter's: a program, not this reader)."""
    from thermal_wild_ns.data.rjpeg import read_rjpeg
    from thermal_wild_ns.data.thermal_io import read_raw_frame

    target = tmp_path / sample.name
    radiometric = sample.suffix == ".jpg" and "thermal" not in sample.parent.name

    def read():
        read_raw_frame(target)
        if radiometric:
            thermal = read_rjpeg(target)
            if thermal.calibration is not None:
                with np.errstate(all="ignore"):  # nonsense constants give NaN °C: a read, not a crash
                    thermal.celsius()

    survives(read, target, sample.read_bytes(), seed=sum(sample.name.encode()))


def _dunr_copy(tmp_path: Path) -> Path:
    root = tmp_path / "dunr"
    root.mkdir()
    (root / "images").symlink_to(DUNR / "images")
    shutil.copyfile(DUNR / "transforms.json", root / "transforms.json")
    shutil.copytree(DUNR / "sparse", root / "sparse")
    return root


@needs_shared
def test_a_damaged_transforms_json_is_read_or_refused_naming_it(tmp_path):
    from thermal_wild_ns.data.layouts import read_nerfstudio

    root = _dunr_copy(tmp_path)
    target = root / "transforms.json"
    survives(lambda: read_nerfstudio(root), target, target.read_bytes(), seed=1)


@needs_shared
@pytest.mark.parametrize("name", ["cameras", "images", "points3D"])
@pytest.mark.parametrize("form", ["txt", "bin"])
def test_a_damaged_colmap_model_is_read_or_refused_naming_it(tmp_path, name, form):
    import pycolmap

    from thermal_wild_ns.data.colmap_layouts import read_colmap

    root = _dunr_copy(tmp_path)
    model = root / "sparse" / "0"
    if form == "bin":  # as COLMAP writes it
        reconstruction = pycolmap.Reconstruction(str(model))
        for text in model.glob("*.txt"):
            text.unlink()
        reconstruction.write_binary(str(model))
    target = model / f"{name}.{form}"
    survives(lambda: read_colmap(root), target, target.read_bytes(), seed=2)


@needs_shared
@pytest.mark.parametrize("name", ["chunk_doc.xml", "FlirModel_XT.xml"])
def test_a_damaged_metashape_file_is_read_or_refused_naming_it(tmp_path, name):
    from thermal_wild_ns.data.metashape import read_lens_calibration, read_metashape_xml

    target = tmp_path / name
    read = read_metashape_xml if name == "chunk_doc.xml" else read_lens_calibration
    survives(lambda: read(target), target, (FLIGHT2 / "metashape" / name).read_bytes(), seed=3)


def test_a_damaged_opensfm_reconstruction_is_read_or_refused_naming_it(tmp_path):
    import layout_fixtures as fx

    from thermal_wild_ns.data.opensfm import read_reconstruction

    fx.write_odm(tmp_path / "survey", n=6)
    target = tmp_path / "survey" / "opensfm" / "reconstruction.json"
    original = json.dumps(json.loads(target.read_text()), indent=1).encode()  # as OpenSfM writes it
    survives(lambda: read_reconstruction(target), target, original, seed=4)
