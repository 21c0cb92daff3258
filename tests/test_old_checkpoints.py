"""Runs saved by earlier versions load as today's (`model/old_checkpoints.py`), and every render takes the one mode
its call asks for (`model/renders.py`)."""

import pytest
import torch
from nerfstudio.data.scene_box import OrientedBox
from test_model import make_camera, make_model

from thermal_wild_ns.errors import InputError
from thermal_wild_ns.model import renders
from thermal_wild_ns.model.old_checkpoints import migrate_config
from thermal_wild_ns.model.renders import RenderMode, render_mode
from thermal_wild_ns.model.wild_thermal import WildThermalModelConfig
from thermal_wild_ns.state_names import CANONICAL, StateName


def old_config(**fields) -> WildThermalModelConfig:
    """A config as nerfstudio rebuilds an older run's config.yml: the dataclass's fields set by name, without its
    constructor, an old field beside today's."""
    config = WildThermalModelConfig()
    vars(config).update(fields)
    return config


def test_an_old_runs_canonical_embedding_is_kept_and_a_name_no_longer_a_state_is_refused():
    config = old_config(inference_embedding="mean")
    migrate_config(config)
    assert config.canonical_embedding == "mean" and "inference_embedding" not in vars(config)
    today = WildThermalModelConfig(canonical_embedding="mean")
    migrate_config(today)  # nothing to convert
    assert today.canonical_embedding == "mean"
    for gone in ("zero", "12"):
        with pytest.raises(InputError, match=f"inference_embedding '{gone}'.*frame:N"):
            migrate_config(old_config(inference_embedding=gone))


def test_a_model_built_from_an_old_config_renders_at_its_canonical_embedding():
    """The mean state the old config asked for, not today's default typical one."""
    model = make_model()
    with torch.no_grad():
        model.frame_embed.weight.normal_()
    vars(model.config)["inference_embedding"] = "mean"
    model.populate_modules()
    with torch.no_grad():
        model.frame_embed.weight.normal_()
        torch.testing.assert_close(model.state_embedding(CANONICAL), model.frame_embed.weight.mean(0))


def test_each_call_takes_one_render_mode():
    assert render_mode(training=True, grad=True, cropped=False, split=False) is RenderMode.TRAINING
    assert render_mode(training=True, grad=True, cropped=False, split=True) is RenderMode.SPLIT_TRAINING
    assert render_mode(training=False, grad=False, cropped=False, split=False) is RenderMode.VIEWING
    assert render_mode(training=False, grad=False, cropped=True, split=False) is RenderMode.CROPPED
    assert render_mode(training=False, grad=False, cropped=False, split=True) is RenderMode.CROPPED
    assert render_mode(training=False, grad=True, cropped=True, split=False) is RenderMode.FITTING


@pytest.mark.parametrize(
    "training, grad, crop, expected",
    [
        (True, True, False, "TrainingRender"),
        (False, False, False, "ViewingRender"),
        (False, False, True, "CroppedRender"),
        (False, True, False, "FittingRender"),
    ],
)
def test_a_render_goes_through_its_modes_render_alone(monkeypatch, training, grad, crop, expected):
    """The model's renders dispatch once: the mode's `render_cameras` runs, no other mode's."""
    model = make_model()
    called = []
    for name in ("TrainingRender", "SplitTrainingRender", "ViewingRender", "CroppedRender", "FittingRender"):
        original = getattr(renders, name).render_cameras
        monkeypatch.setattr(
            getattr(renders, name),
            "render_cameras",
            lambda self, *a, _name=name, _original=original, **k: called.append(_name) or _original(self, *a, **k),
        )
    model.train(training)
    box = OrientedBox(R=torch.eye(3), T=torch.zeros(3), S=torch.full((3,), 100.0)) if crop else None
    with torch.set_grad_enabled(grad):
        if training:
            model.get_outputs(make_camera(1))
        else:
            model.get_outputs_for_camera.__wrapped__(model, make_camera(1), obb_box=box)
    assert called == [expected]


def test_a_state_name_reads_back_as_written_and_a_bad_one_says_what_is_expected():
    for spec in ("canonical", "frame:12", "time:12.5"):
        assert str(StateName.parse(spec)) == spec
    for bad in ("typical", "12", "frame:x", "time:nan", "canonical:1"):
        with pytest.raises(InputError, match="expected canonical, frame:N .* or time:T"):
            StateName.parse(bad)
