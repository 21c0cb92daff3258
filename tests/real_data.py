"""The real captures in `../shared/data` beside the checkout (CI has them; never copied into the repository):
one place for their paths. A test that needs one skips where it is missing, saying where it looked."""

from pathlib import Path

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
DUNR = SHARED_DATA / "dunr"
FLIGHT2 = SHARED_DATA / "flight2"
RJPEG_SAMPLES = SHARED_DATA / "rjpeg_samples"
RGBT_FRAMES = SHARED_DATA / "rgbt_frames"
