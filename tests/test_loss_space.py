"""The photometric loss in the original radiometric space: render and frame both taken back through
the frame's inverse LUT, differentiably."""

import numpy as np
import pytest
import torch

from thermal_wild_ns.demo import demo_trainer_config
from thermal_wild_ns.preprocessing.photometric import PhotometricConfig


@pytest.fixture(scope="module")
def original_space_trainer(tmp_path_factory, demo_scene_dir):
    config = demo_trainer_config(tmp_path_factory.mktemp("loss_space"), steps=2, max_gaussians=3000)
    config.pipeline.datamanager.dataparser.data = demo_scene_dir
    config.pipeline.model.loss_space = "original"
    config.pipeline.datamanager.preprocessing = PhotometricConfig()  # preprocessed (the rule trains the demo raw)
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    return trainer


def test_the_frames_go_back_to_their_captured_values(original_space_trainer):
    pipeline = original_space_trainer.pipeline
    model, dataset = pipeline.model, pipeline.datamanager.train_dataset
    assert model.thermal_loss.inverse_luts is not None and model.thermal_loss.inverse_luts.shape[0] == len(dataset)
    for image in (0, len(dataset) // 2):
        processed = pipeline.datamanager.cached_train[image]["image"].float()  # [H, W, 1]
        back = model.thermal_loss.to_original_space(processed, image)[..., 0].numpy()
        raw = dataset.original_image(image)
        assert np.abs(back - raw).max() < 2e-3 * (raw.max() - raw.min())  # the LUT's own rounding, no more


def test_the_inverse_is_the_sequences_and_carries_gradients(original_space_trainer):
    pipeline = original_space_trainer.pipeline
    model, sequence = pipeline.model, pipeline.datamanager.preprocessed
    image = 3
    t = int(pipeline.datamanager.train_dataset.metadata["frame_indices"][image])
    values = torch.rand(500, generator=torch.Generator().manual_seed(0), requires_grad=True)
    mapped = model.thermal_loss.to_original_space(values, image)
    expected = sequence.to_original_normalised(values.detach().numpy().astype(np.float64), sequence.lut(t))
    assert np.abs(mapped.detach().numpy() - expected).max() < 1e-4
    mapped.sum().backward()
    assert bool((values.grad > 0).all())  # strictly increasing LUTs: every value moves its image


def test_the_loss_is_measured_in_the_original_space(original_space_trainer):
    pipeline = original_space_trainer.pipeline
    model = pipeline.model
    model.train()
    camera, batch = pipeline.datamanager.next_train(0)
    outputs = model.get_outputs(camera)
    losses = model.get_loss_dict(outputs, batch)
    image = int(batch["image_idx"])
    pred = model.thermal_loss.to_original_space(outputs["thermal"], image)
    gt = model.thermal_loss.to_original_space(batch["image"].float(), image)
    _, contrast = model._ground_truth(outputs, batch)
    expected = model.config.l1_lambda * float((gt - pred).abs().mean() / contrast)
    assert float(losses["l1_loss"]) == pytest.approx(expected, rel=1e-4)
    model.config.loss_space = "training"
    try:
        training_space = model.get_loss_dict(outputs, batch)["l1_loss"]
    finally:
        model.config.loss_space = "original"
    assert abs(float(training_space) - float(losses["l1_loss"])) > 1e-6


def test_the_loss_asked_for_cuda_graphs_runs_as_is_on_a_cpu():
    """`graphed_loss` on a CPU: the same terms as without it, and no graph recorded."""
    from thermal_wild_ns.model.thermal_loss import ThermalLoss
    from thermal_wild_ns.model.wild_thermal import WildThermalModelConfig

    torch.manual_seed(0)
    frame, render, alpha, background = (torch.rand(32, 40, 1) for _ in range(4))
    terms, losses = [], []
    for graphed in (True, False):
        loss = ThermalLoss(WildThermalModelConfig(graphed_loss=graphed), None)
        pred = render.clone().requires_grad_()
        outputs = {"thermal": pred, "accumulation": alpha, "background": background}
        gt, contrast = loss.ground_truth(frame, pred, image=0)
        terms.append(loss(outputs, gt, contrast, image=0))
        losses.append(loss)
    assert terms[0].keys() == {"l1_loss", "ssim_loss", "alpha_loss"}
    assert all(torch.equal(terms[0][name], terms[1][name]) for name in terms[1])
    assert losses[0].graphed is not None and not losses[0].graphed.graphs  # asked for, called, none recorded
    assert losses[1].graphed is None


@pytest.mark.parametrize("coupling", ["affine", "mlp"])
def test_the_background_asked_for_cuda_graphs_runs_as_is_on_a_cpu(coupling):
    """`graphed_background` on a CPU: the training background and its gradients as without it, no
    graph recorded."""
    from thermal_wild_ns.model.background import ThermalBackground
    from thermal_wild_ns.model.fields import BackgroundMLP
    from thermal_wild_ns.model.wild_thermal import WildThermalModelConfig

    torch.manual_seed(0)
    mlp = BackgroundMLP(frame_dim=4, frame_coupling=coupling)
    for parameter in mlp.parameters():
        parameter.data.normal_(0.0, 0.3)
    K, pose = torch.tensor([[50.0, 0, 20], [0, 50.0, 16], [0, 0, 1]]), torch.eye(4)[:3]
    embedding = torch.randn(4)
    outputs, grads = [], []
    for graphed in (True, False):
        field = ThermalBackground(mlp, WildThermalModelConfig(graphed_background=graphed))
        mlp.zero_grad(set_to_none=True)
        out = field.training(K, pose, embedding, 40, 32, cam_idx=0)
        out.sum().backward()
        outputs.append(out.detach())
        grads.append([p.grad.clone() for p in mlp.parameters()])
    assert outputs[0].shape == (32, 40, 1) and torch.equal(outputs[0], outputs[1])
    assert all(torch.equal(a, b) for a, b in zip(*grads)) and any(g.abs().sum() > 0 for g in grads[0])
    graphed_field = ThermalBackground(mlp, WildThermalModelConfig(graphed_background=True))
    graphed_field.training(K, pose, embedding, 40, 32, cam_idx=0)
    assert graphed_field.graphed is not None and not graphed_field.graphed.graphs


def test_a_training_frame_is_resized_once_per_size_while_it_is_the_same_unchanged_tensor():
    """`ResizedFrames`: a frame's second visit at one size gets the copy made at its first (no resize), a
    frame changed in place or handed as another tensor is resized again, a new size drops the older copies,
    and at full size nothing is kept (the frame itself, which the cache must not hold)."""
    from thermal_wild_ns.model.thermal_loss import ResizedFrames

    calls = []

    def resize(frame):
        calls.append(frame)
        return frame[::2, ::2].clone()

    frames = ResizedFrames()
    frame = torch.rand(8, 6, 1)
    first = frames.get(3, frame, 2, resize)
    assert frames.get(3, frame, 2, resize) is first and len(calls) == 1
    assert torch.equal(first, frame[::2, ::2])
    frame.mul_(2.0)  # changed in place: its version moves on
    again = frames.get(3, frame, 2, resize)
    assert len(calls) == 2 and torch.equal(again, frame[::2, ::2])
    frames.get(3, frame.clone(), 2, resize)  # the same values in another tensor: resized, not trusted
    assert len(calls) == 3
    frames.get(4, frame, 2, resize)
    assert sorted(frames.kept) == [3, 4]
    frames.get(3, frame, 4, resize)  # a new size: the older copies go
    assert sorted(frames.kept) == [3] and len(calls) == 5
    full = frames.get(3, frame, 1, lambda f: f)
    assert full is frame and not frames.kept
