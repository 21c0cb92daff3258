"""The synthetic drone survey (`data/survey_scene.py`): a capture of any size for the cost and
multi-GPU measurements, in the demo scene's layout."""

import json

import cv2
import numpy as np

from thermal_wild_ns.data.dataparsers import ThermalDemoDataParserConfig
from thermal_wild_ns.data.survey_scene import SurveySceneConfig, camera_to_world, generate_survey_scene


def test_a_survey_is_a_serpentine_of_overlapping_drifting_frames(tmp_path):
    cfg = SurveySceneConfig(num_frames=12, width=64, height=48, focal=113.0, points_per_frame=10)
    rows, per_row, along, across = cfg.layout
    assert rows * per_row >= 12 and along < cfg.height / cfg.focal * cfg.altitude  # neighbours overlap
    folder = generate_survey_scene(tmp_path / "survey", cfg, workers=2)
    meta = json.loads((folder / "transforms.json").read_text())
    assert len(meta["frames"]) == 12 and meta["w"] == 64
    assert meta["val_filenames"] == ["images/frame_00000.png", "images/frame_00008.png"]
    first = cv2.imread(str(folder / meta["frames"][1]["file_path"]), cv2.IMREAD_UNCHANGED)
    assert first.dtype == np.uint16 and first.shape == (48, 64) and first.std() > 0
    assert (folder / meta["frames"][1]["gt_file_path"]).is_file()
    offsets = meta["thermal_demo"]["faults"]["offset"]
    assert offsets[-1] - offsets[0] > 60  # the sensor drifts over the flight
    centres = np.array([camera_to_world(i, cfg)[:3, 3] for i in range(12)])
    steps = np.linalg.norm(np.diff(centres[:, :2], axis=0), axis=1)
    assert np.median(steps) < 1.5 * along  # frame to frame along a row, rows joined end to end
    stamp = (folder / "transforms.json").stat().st_mtime_ns
    generate_survey_scene(folder, cfg)  # up to date: reused, not rewritten
    assert (folder / "transforms.json").stat().st_mtime_ns == stamp


def test_the_demo_parser_generates_and_reads_a_survey(tmp_path):
    parser = ThermalDemoDataParserConfig(data=tmp_path / "survey", scene="survey", survey_frames=9).setup()
    outputs = parser.get_dataparser_outputs(split="train")
    assert len(outputs.image_filenames) == 7  # frames 0 and 8 held out
    assert outputs.cameras.width[0].item() == 640 and len(outputs.metadata["points3D_xyz"]) > 100
