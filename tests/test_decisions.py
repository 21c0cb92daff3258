"""What a run chose and why (`training/decisions.py`): written beside the config when training
starts, completed when it ends, each choice said to come from the capture's data or the config."""

import dataclasses
import json

from thermal_wild_ns.demo import demo_trainer_config
from thermal_wild_ns.pipeline.run_check import PARTIAL_FOLDER
from thermal_wild_ns.training.decisions import DECISIONS_FILE
from thermal_wild_ns.training.trainer import seeded_trainer


def _decisions(trainer):
    path = trainer.config.get_base_dir() / DECISIONS_FILE
    return {d["part"]: d for d in json.loads(path.read_text()) if d["part"] != "Gaussians"}, path


def test_a_run_records_what_it_chose_and_why(tmp_path, demo_scene_dir):
    config = demo_trainer_config(tmp_path, steps=12, max_gaussians=3000)
    config.pipeline.datamanager.dataparser.data = demo_scene_dir
    preprocessing = config.pipeline.datamanager.preprocessing
    config.pipeline.datamanager.preprocessing = dataclasses.replace(preprocessing, variant="stab+bbhe")
    config.auto_stop.enabled = True
    trainer = seeded_trainer(config)
    decisions, path = _decisions(trainer)
    datamanager = trainer.pipeline.datamanager
    # asked to preprocess, the full method lets its stability rule measure the capture: the data decides
    variant, _, reason = datamanager.preprocessing_used.partition(": ")
    assert variant == "none" and reason.startswith("the frames differ by level offsets")  # the demo's
    assert decisions["preprocessing"] == {
        "part": "preprocessing",
        "choice": variant,
        "why": reason,
        "decided_by": "data",
    }
    assert decisions["emission MLP"]["choice"] == "on" and decisions["emission MLP"]["decided_by"] == "config"
    assert decisions["view-dependent emission"]["choice"] == "off"
    assert decisions["training length"]["decided_by"] == "data"  # the automatic stop's frames are held back
    trainer.train()
    decisions, _ = _decisions(trainer)  # rewritten at the end: how the run ended
    assert decisions["training length"]["choice"] == "12 steps"
    assert decisions["training length"]["why"].startswith("--max-num-iterations reached first")
    partial = path.parent / PARTIAL_FOLDER
    assert not partial.exists() or not any(partial.iterdir())  # written whole, by rename


def test_the_config_decides_what_no_rule_measures(tmp_path, demo_scene_dir):
    """The full method's raw frames (its default: no preprocessing asked), a part switched off: both
    said to be the config's choice; the automatic stop, on, is the data's."""
    config = demo_trainer_config(tmp_path, steps=12, max_gaussians=3000)
    config.pipeline.datamanager.dataparser.data = demo_scene_dir
    assert config.pipeline.datamanager.preprocessing.variant == "none"
    config.pipeline.model.use_background_mlp = False
    trainer = seeded_trainer(config)
    decisions = {d.part: d for d in trainer.decisions.collect(trainer)}
    assert decisions["preprocessing"].decided_by == "config" and decisions["preprocessing"].choice == "none (variant)"
    assert "--pipeline.datamanager.preprocessing.variant stab+bbhe" in decisions["preprocessing"].why
    assert decisions["background MLP"].choice == "off"
    assert decisions["training length"].decided_by == "data"  # the demo's automatic stop is on
    assert "held back" in decisions["training length"].why
    # how long it waits, as the schedule set it (12 steps: a check every 10, the patience's 4 checks)
    waits = "every 10 steps; it stops after 4 checks (40 steps) without a 0.05 dB rise"
    assert waits in decisions["training length"].why
