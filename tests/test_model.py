"""WildThermalModel on CPU: forward/backward, densification alignment, bad input, checkpoints."""

import contextlib

import numpy as np
import pytest
import torch
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.data.scene_box import SceneBox
from torch import Tensor

from thermal_wild_ns.errors import InputError
from thermal_wild_ns.model import emission, thermal_loss
from thermal_wild_ns.model.camera_views import ray_directions
from thermal_wild_ns.model.config_checks import UNUSED_OPTIONS
from thermal_wild_ns.model.wild_thermal import WildThermalModelConfig
from thermal_wild_ns.pipeline.ranks import RankGroup
from thermal_wild_ns.state_names import CANONICAL


def background(model, K, c2w, embed, width, height, cam_idx=None, pinhole=None):
    """The model's background as its own renders ask for it (training or not, at its step; `pinhole`: K's fx, fy,
    cx, cy on the host where the caller has them, else read from K)."""
    field = model.parts.background
    if model.training:
        return field.training(K, c2w, embed, width, height, cam_idx)
    if torch.is_grad_enabled():
        return field.exact(K, c2w, embed, width, height)
    return field.rendered(K, c2w, embed, width, height, pinhole, model.step)


def make_model(n=400, frames=5, metadata=None, **overrides):
    """A model of `n` random seed points and `frames` training frames; `metadata`: the training
    dataset's, as the pipeline hands it over (none by default)."""
    g = torch.Generator().manual_seed(0)
    points = torch.randn(n, 3, generator=g) * 0.5
    grey = (torch.rand(n, 1, generator=g) * 255).to(torch.uint8).repeat(1, 3)
    config = WildThermalModelConfig(num_downscales=0, **overrides)
    box = SceneBox(torch.tensor([[-1.0] * 3, [1.0] * 3]))
    extra = {} if metadata is None else {"metadata": metadata}
    return config.setup(scene_box=box, num_train_data=frames, seed_points=(points, grey), **extra)


def unpack_mlp_state(model, state: dict, prefix: str = "") -> None:
    """`model`'s state dict `state` (its keys after `prefix`) rewritten in place as a version before `PackedMLP`
    saved it: each MLP's layers as tensors of their own (`net.0.weight`, `net.0.bias`, ...)."""
    for name in ("emission_mlp", "background_mlp"):
        net = getattr(model, name).net
        for i, layer in enumerate(net.layers(state.pop(f"{prefix}{name}.net.packed"))):
            for part, tensor in zip(("weight", "bias"), layer):
                state[f"{prefix}{name}.net.{2 * i}.{part}"] = tensor.clone()


def as_split(model, world: int = 2):
    """`model` as one GPU's share of a model split across `world` GPUs (what its rules read of it)."""
    model.ranks = RankGroup(0, world)
    model.growth.world = world


def perturb_output_layers(model):
    """As after a few steps: the zero-initialised MLP output layers have moved."""
    with torch.no_grad():
        model.emission_mlp.net.layers()[-1][0].normal_(0, 0.1)
        model.background_mlp.net.layers()[-1][0].normal_(0, 0.1)


def make_frame_dependent_model():
    """A model, in eval mode, whose renders depend on the frame embedding (as after training):
    moved output layers and distinct frame embeddings."""
    model = make_model()
    perturb_output_layers(model)
    with torch.no_grad():
        model.frame_embed.weight.normal_()
    model.eval()
    return model


def make_camera(idx=0, width=48, height=32):
    c2w = torch.eye(4)[None, :3].clone()
    c2w[0, 2, 3] = 3.0  # looking down -z at the origin (OpenGL)
    camera = Cameras(camera_to_worlds=c2w, fx=50.0, fy=50.0, cx=width / 2, cy=height / 2, width=width, height=height)
    camera.metadata = {"cam_idx": idx}
    return camera


def test_forward_backward_reaches_every_parameter_group():
    model = make_model()
    perturb_output_layers(model)
    model.train()
    outputs = model.get_outputs(make_camera(1))
    assert outputs["thermal"].shape == (32, 48, 1) and outputs["rgb"].shape == (32, 48, 3)
    batch = {"image": torch.rand(32, 48, 1), "image_idx": 1}
    losses = model.get_loss_dict(outputs, batch)
    assert set(losses) == {"l1_loss", "ssim_loss", "alpha_loss"}
    sum(losses.values()).backward()
    groups = model.get_param_groups()
    assert {"means", "emission", "gauss_embed", "frame_embed", "emission_mlp", "background_mlp"} <= set(groups)
    for name in ("means", "emission", "opacities", "background_mlp"):
        assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in groups[name]), name
    # only the trained frame's embedding gets gradient
    net = model.emission_mlp.net
    assert net.layers(net.packed.grad)[-1][0].abs().sum() > 0  # the output layer's weights
    frame_grad = model.frame_embed.weight.grad
    assert frame_grad[1].abs().sum() > 0 and frame_grad[[0, 2, 3, 4]].abs().sum() == 0


def test_the_canonical_state_makes_renders_frame_independent():
    model = make_frame_dependent_model()
    a = model.get_outputs(make_camera(0))["thermal"]
    b = model.get_outputs(make_camera(3))["thermal"]
    assert torch.equal(a, b)
    model.train()
    with torch.no_grad():
        c = model.get_outputs(make_camera(3))["thermal"]
    assert not torch.equal(a, c)  # while training each frame uses its own embedding


def test_the_typical_state_renders_closest_to_every_training_frame_on_average():
    """'typical' (docs/design.md): the one state whose emission is nearest, in the expected square over
    the training frames' states, to each frame's. With an emission not linear in the embedding the
    mean embedding is not that state; the typical one does better, and it is kept, not refitted,
    for the next render."""
    model = make_frame_dependent_model()
    with torch.no_grad():
        for weight, _ in model.emission_mlp.net.layers():  # a strongly non-linear emission of the state
            weight.normal_(0, 1.0)
    emission = model.typical_emission()
    frames = [emission(e).detach() for e in model.frame_embed.weight]

    def expected_error(state):
        return torch.stack([(emission(state).detach() - f).square().mean() for f in frames]).mean()

    def avoidable_error(state):  # the expected error less the frames' own spread, which no state changes
        return (emission(state).detach() - torch.stack(frames).mean(0)).square().mean()

    mean = model.frame_states.embedding(CANONICAL, "mean", model.step)
    model.config.canonical_embedding = "typical"
    with torch.no_grad():  # as a render asks for it
        typical = model.state_embedding(CANONICAL)
    assert expected_error(typical) < expected_error(mean)
    assert avoidable_error(typical) < 0.5 * avoidable_error(mean)
    with torch.no_grad():
        assert model.state_embedding(CANONICAL) is typical  # kept until the model changes
    no_mlp = make_model(use_emission_mlp=False, canonical_embedding="typical")
    torch.testing.assert_close(no_mlp.state_embedding(CANONICAL), no_mlp.frame_embed.weight.mean(0))
    # split across GPUs each rank holds a share of the Gaussians: one state on every rank, the mean
    model.ranks = RankGroup(0, 2)
    model.step += 1  # a new key: the kept state is not reused
    with torch.no_grad():
        torch.testing.assert_close(model.state_embedding(CANONICAL), mean)


def test_the_viewer_refits_the_typical_state_at_most_every_few_hundred_steps_while_a_run_trains(monkeypatch):
    """A viewer open during training renders whenever its user moves: the typical state (a fit of its own) is
    refitted for it only once the run has moved `VIEWER_REFIT_STEPS` steps on, or once the step has stood still
    (training paused or done), when it is the exact state of that step again. Renders that name a state
    (evaluation, ns-render) are not throttled."""
    from thermal_wild_ns.model import frame_states

    clock = [100.0]
    monkeypatch.setattr(frame_states.time, "monotonic", lambda: clock[0])
    model = make_frame_dependent_model()
    model.config.canonical_embedding = "typical"
    fits = []
    original = model.typical_emission
    monkeypatch.setattr(model, "typical_emission", lambda: fits.append(model.step) or original())

    def train_step():  # the embeddings change, as an optimizer step changes them
        model.step += 1
        with torch.no_grad():
            model.frame_embed.weight.add_(0.01)

    with torch.no_grad():
        shown = model.viewer_embedding()
        for _ in range(frame_states.VIEWER_REFIT_STEPS - 1):
            train_step()
            clock[0] += 0.01
            assert model.viewer_embedding() is shown  # lags, no refit
        assert fits == [0]
        assert model.state_embedding(CANONICAL) is not shown  # what evaluation reads is the exact state
        train_step()
        refreshed = model.viewer_embedding()
        assert refreshed is not shown and fits[-1] == frame_states.VIEWER_REFIT_STEPS
        train_step()  # the last step of the run
        clock[0] += 0.01
        assert model.viewer_embedding() is refreshed  # still training, as far as the viewer can tell
        clock[0] += frame_states.VIEWER_PAUSE_SECONDS
        exact = model.viewer_embedding()  # the step stood still: the run's own state
        torch.testing.assert_close(exact, model.state_embedding(CANONICAL))
        assert fits[-1] == model.step
        model.config.canonical_embedding = "mean"  # no fit to save: the viewer follows every step
        model.viewer_embedding()
        train_step()
        torch.testing.assert_close(model.viewer_embedding(), model.frame_embed.weight.mean(0))


def test_state_smoothness_penalises_a_frame_state_its_neighbours_do_not_predict():
    """`state_smoothness`: zero while each training frame's embedding lies on the line its neighbours
    in capture time draw (the `time` protocol's prediction, `at`), also with unevenly spaced frames; a
    kinked state pays exactly what `at` misses it by, its gradient pulls it back towards the line, and
    the term is in the training loss only when asked for."""
    metadata = {"frame_indices": [0, 1, 3, 4, 7]}  # the rows' capture positions
    model = make_model(frames=5, metadata=metadata, state_smoothness=2.0)
    times = torch.tensor([0.0, 1.0, 3.0, 4.0, 7.0])[:, None]
    with torch.no_grad():
        model.frame_embed.weight.copy_(0.1 + 0.05 * times * torch.ones(1, model.frame_embed.weight.shape[1]))
    assert model.frame_states.neighbour_residual().item() == pytest.approx(0.0, abs=1e-10)
    with torch.no_grad():
        model.frame_embed.weight[3] += 0.3  # the frame at position 4 off the line
    residual = model.frame_states.neighbour_residual()
    assert residual.item() > 0
    states = model.frame_states  # `at` predicting each middle frame from the others
    missed = [model.frame_embed.weight[r] - states.at(states.frame_times[r], without=[r]) for r in (1, 2, 3)]
    assert residual.item() == pytest.approx(torch.stack(missed).square().mean().item(), rel=1e-6)
    residual.backward()
    assert float(model.frame_embed.weight.grad[3].sum()) > 0  # descending moves it back down
    perturb_output_layers(model)
    model.train()
    batch = {"image": torch.rand(32, 48, 1), "image_idx": 1}
    losses = model.get_loss_dict(model.get_outputs(make_camera(1)), batch)
    assert losses["state_smoothness"].item() == pytest.approx(2.0 * residual.item(), rel=1e-5)
    plain = make_model(frames=5, metadata=metadata)
    plain.train()
    assert "state_smoothness" not in plain.get_loss_dict(plain.get_outputs(make_camera(1)), batch)


def test_densification_keeps_embeddings_aligned():
    model = make_model(n=200)
    params, optimizers = model.gauss_params, {}
    for name, p in params.items():
        optimizers[name] = torch.optim.Adam([p], lr=1e-3)
    # tag each Gaussian: its embedding's first entry equals its emission
    with torch.no_grad():
        params["gauss_embed"][:, 0] = params["emission"][:, 0] = torch.arange(200, dtype=torch.float32)
    state = model.strategy_state
    state["grad2d"] = torch.zeros(200)
    state["count"] = torch.ones(200)
    state["radii"] = torch.zeros(200)
    state["grad2d"][:50] = 1.0  # grow the first 50
    model.strategy._grow_gs(params, optimizers, state, step=model.strategy.refine_start_iter + 1)
    assert params["means"].shape[0] > 200
    torch.testing.assert_close(params["gauss_embed"][:, 0], params["emission"][:, 0])
    keep = torch.ones(params["means"].shape[0], dtype=torch.bool)
    keep[::3] = False
    from gsplat.strategy.ops import remove

    remove(params=params, optimizers=optimizers, state={}, mask=~keep)
    torch.testing.assert_close(params["gauss_embed"][:, 0], params["emission"][:, 0])
    assert all(p.shape[0] == params["means"].shape[0] for p in params.values())
    assert all(optimizers[k].param_groups[0]["params"][0] is params[k] for k in params)


def test_gaussian_budget_caps_growth():
    model = make_model(n=200, max_gaussians=230)
    params = model.gauss_params
    optimizers = {k: torch.optim.Adam([p], lr=1e-3) for k, p in params.items()}
    state = model.strategy_state
    state.update(grad2d=torch.ones(200), count=torch.ones(200), radii=torch.zeros(200))
    model.strategy._grow_gs(params, optimizers, state, step=model.strategy.refine_start_iter + 1)
    assert params["means"].shape[0] == 230


def test_growth_stops_where_gpu_memory_ends_and_says_so():
    model = make_model(n=200, max_gaussians=1000)
    model.strategy.memory_room = lambda n, device, row_bytes: 10  # the device holds 10 more Gaussians
    params = model.gauss_params
    optimizers = {k: torch.optim.Adam([p], lr=1e-3) for k, p in params.items()}
    model.strategy_state.update(grad2d=torch.ones(200), count=torch.ones(200), radii=torch.zeros(200))
    model.strategy._grow_gs(params, optimizers, model.strategy_state, step=model.strategy.refine_start_iter + 1)
    assert params["means"].shape[0] == 210
    assert model.strategy.memory_stopped_at == 200
    assert make_model(n=20).strategy.memory_room(20, torch.device("cpu"), 64) is None  # no limit known off CUDA


def test_the_memory_estimate_leaves_room_for_the_peak_and_the_growth(monkeypatch):
    """A device of 1,000 bytes whose peak at 100 Gaussians was 400 (4 per Gaussian), rows of 1 byte:
    0.85 x 1000 - 400 - 2 x 1 x 100 = 250 bytes left, room for 62 more Gaussians."""
    from types import SimpleNamespace

    from thermal_wild_ns.model import strategy

    monkeypatch.setattr(torch.cuda, "get_device_properties", lambda device: SimpleNamespace(total_memory=1000))
    monkeypatch.setattr(torch.cuda, "max_memory_allocated", lambda device: 400)
    assert strategy.gaussians_memory_holds(100, torch.device("cuda"), 1) == 62
    monkeypatch.setattr(torch.cuda, "max_memory_allocated", lambda device: 900)
    assert strategy.gaussians_memory_holds(100, torch.device("cuda"), 1) == 0  # past the headroom: no growth


def test_pruning_is_skipped_where_its_copies_do_not_fit(monkeypatch):
    """A pruning copies each parameter and its Adam moments: where that does not fit beside what the
    GPU holds, the round prunes nothing (instead of running out of memory with half the parameters
    pruned) and says so; where it fits, it prunes."""
    from types import SimpleNamespace

    from thermal_wild_ns.model import strategy

    model = make_model(n=200)
    params = model.gauss_params
    optimizers = {k: torch.optim.Adam([p], lr=1e-3) for k, p in params.items()}
    with torch.no_grad():
        params["opacities"][:50] = -10.0  # 50 transparent Gaussians: pruned whenever pruning runs
    step = model.strategy.refine_start_iter + 1
    model.strategy.copies_fit = lambda n, device, row_bytes: False
    assert model.strategy._prune_gs(params, optimizers, model.strategy_state, step) == 0
    assert params["means"].shape[0] == 200 and model.strategy.prunes_skipped == 1
    model.strategy.copies_fit = lambda n, device, row_bytes: True
    assert model.strategy._prune_gs(params, optimizers, model.strategy_state, step) >= 50
    # the rule: 1,000 bytes of device, 0.85 of it usable; rows of 1 byte, 100 Gaussians: 300 bytes of copies
    monkeypatch.setattr(torch.cuda, "get_device_properties", lambda device: SimpleNamespace(total_memory=1000))
    monkeypatch.setattr(torch.cuda, "memory_allocated", lambda device: 550)
    assert strategy.refinement_copies_fit(100, torch.device("cuda"), 1)  # 550 + 300 <= 850
    monkeypatch.setattr(torch.cuda, "memory_allocated", lambda device: 551)
    assert not strategy.refinement_copies_fit(100, torch.device("cuda"), 1)
    assert strategy.refinement_copies_fit(10**9, torch.device("cpu"), 64)  # no limit known off CUDA


def test_densification_reads_the_render_layout_it_was_given():
    """Across GPUs the render is packed (one row per visible splat): the statistics must count each
    splat for its own Gaussian. Read as [cameras, Gaussians] (splatfacto passes packed=False) every
    splat was summed into every Gaussian, the screen-size rule pruned all of them, and two-GPU runs
    collapsed after the first opacity reset."""
    model = make_model(n=4, frames=2, use_absgrad=False)  # gsplat's distributed mode has no absgrad
    strategy, state = model.strategy, model.strategy_state
    means2d = torch.zeros(3, 2, requires_grad=True)
    (means2d * torch.tensor([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])).sum().backward()
    packed = {"gaussian_ids": torch.tensor([0, 0, 2]), "radii": torch.tensor([3, 5, 4]), "means2d": means2d}
    info = {**packed, "width": 100, "height": 50, "n_cameras": 1}
    strategy._update_state(model.gauss_params, state, info, packed=True)
    assert state["count"].tolist() == [2.0, 0.0, 1.0, 0.0]  # Gaussian 0 seen twice (two cameras), 2 once
    torch.testing.assert_close(state["radii"], torch.tensor([0.05, 0.0, 0.04, 0.0]))  # over the longer side
    with pytest.raises(ValueError, match=r"radii \(3,\) are not \[C, N\]"):
        strategy._update_state(model.gauss_params, state, info, packed=False)
    # the model hands the strategy the layout it rendered with
    seen = {}
    strategy.step_post_backward = lambda **kwargs: seen.update(kwargs)
    model.info = info  # the last render's, as the training step leaves it
    model.ranks = RankGroup(0, 2)
    model.step_post_backward(model.step)
    assert seen["packed"] is True
    model.ranks = RankGroup()
    model.step_post_backward(model.step)
    assert seen["packed"] is False


def test_bad_input_is_reported_or_skipped():
    model = make_model()
    model.train()
    outputs = model.get_outputs(make_camera(0))
    with pytest.raises(ValueError, match="single-channel"):
        model.get_loss_dict(outputs, {"image": torch.rand(32, 48, 3), "image_idx": 0})
    image = torch.rand(32, 48, 1)
    image[:5] = float("nan")
    losses = model.get_loss_dict(outputs, {"image": image, "image_idx": 0})
    assert all(torch.isfinite(v) for v in losses.values())  # NaN pixels are left out, with a warning
    with pytest.raises(ValueError, match="at least 4 seed points"):
        make_model(n=2)
    with pytest.raises(ValueError, match="canonical_embedding"):
        model = make_model(canonical_embedding="99")
        model.eval()
        model.get_outputs(make_camera(0))
    model = make_model()
    model.train()
    for name, p in list(model.gauss_params.items()):
        model.gauss_params[name] = torch.nn.Parameter(p[:0])
    with pytest.raises(RuntimeError, match="pruned"):
        model.get_outputs(make_camera(0))
    model.eval()
    empty = model.get_outputs(make_camera(0))  # rendering an empty model shows the background
    torch.testing.assert_close(empty["thermal"], empty["background"])


def test_baseline_variant_has_no_mlp():
    model = make_model(use_emission_mlp=False, use_background_mlp=False)
    assert model.emission_mlp is None and "gauss_embed" not in model.gauss_params
    model.train()
    out = model.get_outputs(make_camera(0))
    sum(model.get_loss_dict(out, {"image": torch.rand(32, 48, 1), "image_idx": 0}).values()).backward()
    assert model.emission.grad.abs().sum() > 0
    assert set(model.get_param_groups()) == {"means", "scales", "quats", "emission", "opacities", "frame_embed"}


def test_nonnegative_emission_renders_a_negative_gaussian_as_a_black_one():
    """With `nonnegative_emission` a Gaussian below zero occludes like a black one and subtracts
    nothing, in training renders and in renders outside training; without it, it subtracts."""

    def render(nonnegative: bool, value: float, training: bool) -> torch.Tensor:
        model = make_model(use_emission_mlp=False, use_background_mlp=False, nonnegative_emission=nonnegative)
        with torch.no_grad():
            model.emission[::2] = value  # half the Gaussians
        model.train(training)
        with torch.set_grad_enabled(training):
            return model.get_outputs(make_camera(0))["thermal"].detach()

    for training in (True, False):
        black = render(False, 0.0, training)
        assert torch.allclose(render(True, -0.5, training), black, atol=1e-6)
        assert (render(False, -0.5, training) < black - 1e-3).any()  # unclamped, the Gaussians subtract


def test_graphed_calls_record_once_per_shape_and_replay_after(monkeypatch):
    """`GraphedCalls` bookkeeping, with a stand-in recording on a CPU: one recording per key and input
    shapes, replayed after."""
    from thermal_wild_ns.model.graphed import GraphedCalls

    recorded = []

    def stand_in(fn, samples):
        recorded.append(tuple(t.shape[0] for t in samples))
        return lambda *inputs: tuple(2 * out for out in fn(*inputs))  # tells a replay from a plain call

    monkeypatch.setattr(GraphedCalls, "records", staticmethod(lambda inputs: True))
    monkeypatch.setattr(GraphedCalls, "_record", staticmethod(stand_in))

    def fn(x):
        return (x + 1,)

    calls = GraphedCalls("test")
    for n in (5, 5, 7, 5):
        (out,) = calls(None, fn, torch.zeros(n, 2))
        assert torch.equal(out, torch.full((n, 2), 2.0))  # the recording's output, not fn's
    assert recorded == [(5,), (7,)]
    assert len(calls.graphs) == 2


def eager_rows_recording(fn, shapes, capacity, rows, shared, parameters, aliases):
    """A stand-in for `PaddedRowCalls._record` on a CPU: a `RowsRecording` whose two replays run `fn` on
    the static inputs and the parameters' aliases, and its backward into the static gradients, as the
    recorded graphs would."""
    from thermal_wild_ns.model.graphed import RowsRecording

    inputs = rows + shared
    surface = inputs + aliases
    with torch.enable_grad():
        output = fn(*inputs)
    grads = tuple(torch.zeros_like(t) if t.requires_grad else None for t in surface)
    last = {}

    def forward():
        with torch.enable_grad():
            last["out"] = fn(*inputs)
        output.detach().copy_(last["out"])

    def backward():
        wanted = [t for t in surface if t.requires_grad]
        found = iter(torch.autograd.grad(last["out"], wanted, grad_output, allow_unused=True))
        for buffer, t in zip(grads, surface):
            if t.requires_grad:
                value = next(found)
                buffer.copy_(torch.zeros_like(buffer) if value is None else value)

    grad_output = torch.zeros_like(output)
    return RowsRecording(
        shapes, capacity, rows, shared, parameters, output.detach(), grad_output, grads, forward, backward
    )


def test_padded_row_calls_replay_one_recording_for_the_counts_densification_moves_through(monkeypatch):
    """`PaddedRowCalls` (the emission MLP's graphs), with an eager stand-in recording on a CPU: the
    Gaussian count grown, kept and pruned within a capacity replays one recording, and its emission and
    every gradient (per-Gaussian scalars and embeddings, the frame embedding, the MLP's parameters) are the
    plain MLP's, the parameters changed in place between steps; rows past the count are zero, so they add
    nothing to a gradient; the recording reads the parameters through leaves that share their memory; a count
    past the capacity, or under half of it, is recorded again (the latest alone kept), and each slot has its
    own."""
    from thermal_wild_ns.model.fields import EmissionMLP
    from thermal_wild_ns.model.graphed import PaddedRowCalls, row_capacity

    recorded = []

    def stand_in(fn, shapes, capacity, rows, shared, parameters, aliases):
        recorded.append(capacity)
        # recorded on leaves of the parameters' memory, never on the parameters (whose gradient nodes the last
        # step's loss keeps on the step's stream: a capture that reaches them fails on a GPU)
        assert parameters == tuple(mlp.parameters()) and len(aliases) == len(parameters)
        for alias, parameter in zip(aliases, parameters):
            assert alias is not parameter and alias.is_leaf and alias.data_ptr() == parameter.data_ptr()
        return eager_rows_recording(fn, shapes, capacity, rows, shared, parameters, aliases)

    monkeypatch.setattr(PaddedRowCalls, "records", staticmethod(lambda inputs: True))
    monkeypatch.setattr(PaddedRowCalls, "_record", staticmethod(stand_in))
    torch.manual_seed(0)
    mlp = EmissionMLP(4, 3, width=8, hidden_layers=2).double()
    for parameter in mlp.parameters():  # the zero-initialised output layer would give zero gradients upstream
        parameter.data.normal_(0.0, 0.5)
    calls = PaddedRowCalls("emission MLP")
    frames = torch.nn.Parameter(torch.randn(3, 3, dtype=torch.float64))
    counts = (1500, 1600, 1450, 3000, 1200, 700)
    for step, count in enumerate(counts):
        base = torch.nn.Parameter(torch.rand(count, 1, dtype=torch.float64))
        embed = torch.nn.Parameter(torch.randn(count, 4, dtype=torch.float64))
        weights = torch.rand(count, 1, dtype=torch.float64)
        results = []
        for run in (lambda *x: calls(mlp, x[:2], x[2:]), mlp):
            for leaf in (base, embed, frames, *mlp.parameters()):
                leaf.grad = None
            out = run(base, embed, frames[step % 3])
            (out * weights).sum().backward()
            grads = [base.grad.clone(), embed.grad.clone(), frames.grad.clone()]
            results.append((out.detach().clone(), grads + [p.grad.clone() for p in mlp.parameters()]))
        (ours, ours_grads), (reference, reference_grads) = results
        assert ours.shape == (count, 1) and torch.allclose(ours, reference, rtol=1e-12, atol=1e-12), step
        for mine, theirs in zip(ours_grads, reference_grads):
            assert mine.shape == theirs.shape and torch.allclose(mine, theirs, rtol=1e-10, atol=1e-12), step
        recording = calls.recordings[0]
        assert float(recording.row_inputs[1][count:].detach().abs().sum()) == 0.0  # the padded rows
        assert float(recording.grad_output[count:].abs().sum()) == 0.0
        with torch.no_grad():  # an optimizer step, in place: the recording reads the parameters where they live
            for parameter in mlp.parameters():
                parameter.add_(0.05 * torch.randn_like(parameter))
    assert (row_capacity(1500), row_capacity(1600), row_capacity(3000), row_capacity(11585)) == (
        1536,
        2048,
        3072,
        11776,
    )
    # 1450 replays 2048's; 1200 is under half of 3072, 700 of 1536
    assert recorded == [1536, 2048, 3072, 1536, 1024]
    calls(mlp, (torch.zeros(10, 1, dtype=torch.float64), torch.zeros(10, 4, dtype=torch.float64)), (frames[0],), slot=1)
    assert set(calls.recordings) == {0, 1} and recorded[-1] == 1024


def test_a_recording_leaves_the_callers_module_as_it_was(monkeypatch):
    """`torch.cuda.make_graphed_callables` replaces a module's `forward` with the replay of its one
    recording (mimicked here on a CPU, shapes checked as a replay checks them): `GraphedCalls` hands
    it a fresh wrapper, so the emission MLP still runs at a new Gaussian count, recorded again or
    called plainly (on a GPU the first version failed here: a 4,000-row recording fed 6,000 rows)."""
    from thermal_wild_ns.model.graphed import GraphedCalls

    def like_torch(module, samples, allow_unused_input=False):
        shapes = [t.shape for t in samples]

        def replay(*inputs):
            assert [t.shape for t in inputs] == shapes, "a replay takes its recording's shapes only"
            return type(module).forward(module, *inputs)

        module.forward = replay  # what torch does to a module it records
        return module

    monkeypatch.setattr(GraphedCalls, "records", staticmethod(lambda inputs: True))
    monkeypatch.setattr(torch.cuda, "make_graphed_callables", like_torch)
    mlp = torch.nn.Linear(2, 1)
    calls = GraphedCalls("test")
    for n in (5, 7):
        assert calls(None, mlp, torch.zeros(n, 2)).shape == (n, 1)
    assert mlp(torch.zeros(9, 2)).shape == (9, 1)  # the caller's module, called plainly
    assert [p.requires_grad for p in mlp.parameters()] == [True, True]


def test_graphed_emission_on_a_cpu_trains_as_without_it():
    """`graphed_emission` on a CPU: the same emission and gradients as without it, nothing recorded."""
    results = []
    for graphed in (True, False):
        torch.manual_seed(0)  # the same Gaussians, embeddings and networks twice
        model = make_model(graphed_emission=graphed)
        perturb_output_layers(model)
        model.train()
        outputs = model.get_outputs(make_camera(1))
        sum(
            model.get_loss_dict(
                outputs, {"image": torch.rand(32, 48, 1, generator=torch.Generator().manual_seed(0)), "image_idx": 1}
            ).values()
        ).backward()
        results.append((outputs["thermal"].detach(), [p.grad.clone() for p in model.emission_mlp.parameters()], model))
    (ours, ours_grads, graphed_model), (reference, reference_grads, plain_model) = results
    assert torch.equal(ours, reference) and all(torch.equal(a, b) for a, b in zip(ours_grads, reference_grads))
    assert graphed_model.parts.emission.graphed is not None and not graphed_model.parts.emission.graphed.recordings
    assert plain_model.parts.emission.graphed is None


def test_every_attribute_nerfstudio_tools_read_is_available():
    """ns-viewer walks every attribute of the model (viewer/utils.py parse_object); exporters read
    the SH accessors. All must work on a model without spherical harmonics."""
    model = make_model()
    for name in dir(model):
        getattr(model, name)
    assert model.features_dc.shape == (model.num_points, 3) and model.shs_rest.shape == (model.num_points, 0, 3)


def test_baked_emission_matches_and_is_invalidated(monkeypatch):
    """Outside training the emission MLP runs once per embedding and parameter state; the baked
    render equals the unbaked one and follows any change of either. (No background MLP: its own
    baked map has its own test.) The bake runs a few Gaussians at a time, as a model of hundreds of
    millions needs."""
    model, camera = make_model(use_background_mlp=False), make_camera()
    monkeypatch.setattr(emission, "BAKE_ROWS", model.num_points // 3 + 1)  # three parts, the last shorter
    with torch.no_grad():  # a zero output layer would make every embedding render alike
        model.emission_mlp.net.layers()[-1][0].normal_(0, 0.1)
    model.eval()
    with torch.enable_grad():  # autograd on: no baking, the MLP runs on every render
        unbaked = model.get_outputs(camera)["thermal"].detach()
    with torch.no_grad():
        baked = model.get_outputs(camera)["thermal"]
        first = model.parts.emission.baked_values.slots["emission"][2]
        assert (
            model.get_outputs(camera)["thermal"].equal(baked)
            and model.parts.emission.baked_values.slots["emission"][2] is first
        )  # reused
    torch.testing.assert_close(baked, unbaked, atol=1e-5, rtol=0)
    with torch.no_grad():
        model.emission_mlp.net.layers()[0][0].add_(0.01)  # an optimizer step changes parameters in place
        changed = model.get_outputs(camera)["thermal"]
        assert model.parts.emission.baked_values.slots["emission"][2] is not first and not changed.equal(baked)
        second = model.parts.emission.baked_values.slots["emission"][2]
        model.get_outputs(camera, frame_embedding=torch.ones_like(model.frame_embed.weight[0]))  # another state
        assert model.parts.emission.baked_values.slots["emission"][2] is not second
    # a training step with fused Adam (which leaves tensor versions alone) invalidates it too
    optimizer = torch.optim.Adam([*model.emission_mlp.parameters(), model.frame_embed.weight], lr=0.1, fused=True)
    with torch.no_grad():
        before_step = model.get_outputs(camera)["thermal"]
        third = model.parts.emission.baked_values.slots["emission"][2]
    for param in [*model.emission_mlp.parameters(), model.frame_embed.weight]:
        param.grad = torch.ones_like(param)
    optimizer.step()
    model.step += 1  # what the trainer's step callback does
    with torch.no_grad():
        after_step = model.get_outputs(camera)["thermal"]
    assert model.parts.emission.baked_values.slots["emission"][2] is not third and not after_step.equal(before_step)


def test_a_render_outside_training_equals_the_general_path():
    """Renders a user waits for take their own path (`viewing_view_and_background`, `viewing_outputs`:
    on a GPU replayed as CUDA graphs); every output equals the general path's, which a crop box that
    holds every Gaussian takes, with and without the background MLP."""
    from nerfstudio.data.scene_box import OrientedBox

    torch.manual_seed(0)
    for background_mlp, coupling in ((True, "mlp"), (True, "affine"), (False, "mlp")):
        model = make_model(use_background_mlp=background_mlp, background_frame_coupling=coupling)
        if background_mlp:
            perturb_output_layers(model)
            if model.background_mlp.frame_affine is not None:
                model.background_mlp.frame_affine.weight.data.normal_(0, 0.1)
        else:
            model.emission_mlp.net.layers()[-1][0].data.normal_(0, 0.1)
        model.eval()
        everything = OrientedBox(R=torch.eye(3), T=torch.zeros(3), S=torch.full((3,), 100.0))
        for camera in (make_camera(1, width=64, height=48), make_camera(2, width=40, height=24)):
            camera.camera_to_worlds[0, 0, 3] = 0.3 * camera.width.item() / 64  # another pose each
            with torch.no_grad():
                viewing = model.get_outputs_for_camera(camera)
                general = model.get_outputs_for_camera(camera, obb_box=everything)
            assert set(viewing) == set(general)
            for name, value in general.items():
                assert viewing[name].shape == value.shape and torch.equal(viewing[name], value), name
            assert float(viewing["accumulation"].max()) > 0.1  # Gaussians in view: a render, not only background


def test_the_background_mlps_size_and_coupling_come_from_the_config():
    """`background_mlp_width`, `background_mlp_layers` and `background_frame_coupling` build the background
    MLP the model trains (what a size sweep varies), and the default couples the frame as a gain and offset."""
    weights = lambda model: [tuple(weight.shape) for weight, _ in model.background_mlp.net.layers()]  # [out, in]
    default = make_model()
    # 'affine' (the default) feeds the MLP the directions' encoding (16) only; 'mlp' the frame embedding (16) too
    assert weights(default) == [(64, 16), (64, 64), (1, 64)]
    assert default.background_mlp.frame_affine is not None  # 'affine' by default
    small = make_model(background_mlp_width=16, background_mlp_layers=1, background_frame_coupling="mlp")
    assert weights(small) == [(16, 32), (1, 16)]
    assert small.background_mlp.frame_affine is None


def test_each_mlp_is_one_parameter_that_a_checkpoint_of_its_separate_layers_loads_into():
    """An MLP's weights and biases are views of one parameter (`PackedMLP`: one gradient to accumulate and one
    tensor for Adam each step), drawn as `nn.Linear` layers draw theirs; a checkpoint from before, whose MLPs
    were `nn.Sequential` layers, loads into a model of now and renders the same."""
    from torch import nn

    from thermal_wild_ns.model.fields import PackedMLP
    from thermal_wild_ns.model.old_checkpoints import packed_mlp_state

    def separate(in_dim, width, hidden_layers):  # the MLP before the packing, as `mlp()` built it
        layers = []
        for dim in [in_dim] + [width] * (hidden_layers - 1):
            layers += [nn.Linear(dim, width), nn.ReLU(inplace=True)]
        out = nn.Linear(width, 1)
        nn.init.zeros_(out.weight)
        nn.init.zeros_(out.bias)
        return nn.Sequential(*layers, out)

    torch.manual_seed(0)
    old = separate(24, 32, 3)
    torch.manual_seed(0)
    packed = PackedMLP(24, 32, 3)
    assert [name for name, _ in packed.named_parameters()] == ["packed"]
    assert torch.equal(packed.packed, torch.cat([p.detach().reshape(-1) for p in old.parameters()]))  # same draws
    with torch.no_grad():
        old[-1].weight.normal_()  # as after training
    packed.load_state_dict(packed_mlp_state(old.state_dict(), "", packed.shapes))
    x = torch.randn(50, 24)
    assert torch.equal(packed(x), old(x))
    packed(x).square().sum().backward()
    old(x).square().sum().backward()
    assert torch.equal(packed.packed.grad, torch.cat([p.grad.reshape(-1) for p in old.parameters()]))

    model = make_model()
    perturb_output_layers(model)
    state = model.state_dict()
    unpack_mlp_state(model, state)
    assert "emission_mlp.net.0.weight" in state and "emission_mlp.net.packed" not in state
    before = make_model()
    before.load_state_dict(state)
    model.eval()
    before.eval()
    with torch.no_grad():
        assert torch.equal(before.get_outputs(make_camera(2))["thermal"], model.get_outputs(make_camera(2))["thermal"])


def test_adam_states_of_separate_layers_pack_as_the_packed_mlp_would_have_them():
    """`packed_adam_state`: Adam stepped on an MLP's separate layers (beside a tensor before and one after them,
    as a background MLP's offset and affine layer) has, packed, the state Adam stepped on the `PackedMLP` has;
    with a layer never stepped the packed tensor starts without state."""
    from torch import nn

    from thermal_wild_ns.model.fields import PackedMLP
    from thermal_wild_ns.model.old_checkpoints import packed_adam_state

    torch.manual_seed(0)
    packed = PackedMLP(6, 8, 2)
    layers = [t.detach().clone().requires_grad_() for w, b in packed.layers() for t in (w, b)]
    before, after = nn.Parameter(torch.randn(1)), nn.Parameter(torch.randn(2, 3))
    separate = torch.optim.Adam([before, *layers, after], lr=0.1)
    together = torch.optim.Adam([before, packed.packed, after], lr=0.1)
    for _ in range(3):
        grads = [torch.randn_like(t) for t in layers]
        for t, g in zip(layers, grads):
            t.grad = g
        packed.packed.grad = torch.cat([g.reshape(-1) for g in grads])
        before.grad, after.grad = torch.randn_like(before), torch.randn_like(after)
        separate.step()
        together.step()
    converted = packed_adam_state(separate.state_dict(), 1, len(layers))
    expected = together.state_dict()
    assert converted["param_groups"][0]["params"] == expected["param_groups"][0]["params"] == [0, 1, 2]
    for i in range(3):
        for key, value in expected["state"][i].items():
            assert torch.equal(converted["state"][i][key], value), (i, key)
    fresh = separate.state_dict()
    del fresh["state"][2]  # a layer with no state yet
    assert sorted(packed_adam_state(fresh, 1, len(layers))["state"]) == [0, 2]


def test_an_affine_background_changes_every_direction_alike_from_frame_to_frame():
    """`background_frame_coupling` 'affine': the frame embedding sets a gain and an offset of a direction-only
    map, so one frame's background is an affine map of another's over every direction; 'mlp' (the frame
    embedding an input of the MLP) can change each direction its own way. Both start at `init_value`."""
    from thermal_wild_ns.model.fields import BackgroundMLP

    torch.manual_seed(0)
    dirs = torch.nn.functional.normalize(torch.randn(6, 5, 3), dim=-1)  # [6, 5, 3]
    first, second = torch.randn(8), torch.randn(8)
    residual = {}
    for coupling in ("mlp", "affine"):
        background = BackgroundMLP(8, init_value=0.3, frame_coupling=coupling)
        assert torch.allclose(background(dirs, first), torch.full((6, 5, 1), 0.3))  # zero-initialised outputs
        with torch.no_grad():
            for parameter in background.parameters():
                parameter.normal_()
            a, b = background(dirs, first).flatten(), background(dirs, second).flatten()  # [30]
        basis = torch.stack([a, torch.ones_like(a)], 1)  # [30, 2]
        fit = basis @ torch.linalg.lstsq(basis, b[:, None]).solution
        residual[coupling] = float((fit[:, 0] - b).abs().max() / b.abs().max())
    assert residual["affine"] < 1e-5 and residual["mlp"] > 1e-2
    with pytest.raises(ValueError, match="'mlp' or 'affine'"):
        BackgroundMLP(8, frame_coupling="sky")


def test_mismatched_checkpoints_are_refused_with_the_reason():
    state = make_model().state_dict()
    with pytest.raises(
        ValueError, match=r"checkpoint has the emission MLP \(use_emission_mlp\) but this config disables it"
    ):
        make_model(use_emission_mlp=False).load_state_dict(dict(state))
    with pytest.raises(ValueError, match=r"checkpoint lacks the background MLP"):
        make_model().load_state_dict({k: v for k, v in state.items() if not k.startswith("background_mlp.")})
    with pytest.raises(ValueError, match=r"checkpoint has 5 frame embeddings of size 16, this config 7 of size 16"):
        make_model(frames=7).load_state_dict(dict(state))
    make_model().load_state_dict(dict(state))  # a matching one loads


def test_a_checkpoint_of_the_other_background_coupling_renders_as_trained_and_is_refused_for_a_resume():
    """A run from before `affine` became the default has no coupling in its config.yml, so it loads under
    `affine`: to render, the model takes the checkpoint's `mlp` background and renders what it trained; to resume
    (training mode), the optimizers already hold the other background's parameters: refused, naming the flag."""
    torch.manual_seed(0)
    old = make_model(background_frame_coupling="mlp")
    perturb_output_layers(old)
    old.eval()
    state = old.state_dict()
    camera = make_camera(1, width=40, height=32)
    with torch.no_grad():
        expected = old.get_outputs_for_camera(camera)["thermal"]
    with pytest.raises(ValueError, match="--pipeline.model.background-frame-coupling mlp"):
        make_model().load_state_dict(dict(state))  # a fresh model trains: a resume
    loaded = make_model()
    loaded.eval()
    loaded.load_state_dict(dict(state))
    assert loaded.config.background_frame_coupling == "mlp" and loaded.background_mlp.frame_affine is None
    with torch.no_grad():
        assert torch.equal(loaded.get_outputs_for_camera(camera)["thermal"], expected)


def test_background_is_cached_per_training_camera_and_smooth_enough_for_its_grid():
    model = make_model()
    perturb_output_layers(model)
    model.train()
    camera = make_camera(2, width=160, height=128)
    camera.fx[:] = camera.fy[:] = 200.0  # a 44 degree field of view, like DUNR's
    K, c2w = camera.get_intrinsics_matrices()[0], camera.camera_to_worlds[0]
    embed = model.frame_embed.weight[2]
    with torch.no_grad():
        fresh = background(model, K, c2w, embed, 160, 128)
        cached = background(model, K, c2w, embed, 160, 128, cam_idx=2)
        assert (2, 160, 128) in model.parts.background._encoded_directions
        again = background(model, K, c2w, embed, 160, 128, cam_idx=2)
        model.config.background_stride = 1
        full = background(model, K, c2w, embed, 160, 128)
    assert torch.equal(fresh, cached) and torch.equal(cached, again)
    assert fresh.shape == full.shape == (128, 160, 1)
    spread = float(full.max() - full.min())
    assert spread > 0 and float((fresh - full).abs().max()) < 0.05 * spread


def test_ssim_matches_pytorch_msssim():
    from pytorch_msssim import ssim as reference

    from thermal_wild_ns.image_metrics import ssim

    g = torch.Generator().manual_seed(1)
    x = torch.rand(40, 56, 1, generator=g)
    y = (x + 0.1 * torch.randn(40, 56, 1, generator=g)).clamp(0, 1)
    expected = reference(x.permute(2, 0, 1)[None], y.permute(2, 0, 1)[None], data_range=1.0, size_average=True)
    assert abs(float(ssim(x, y)) - float(expected)) < 1e-5


def test_sync_free_densification_statistics_equal_gsplats():
    from gsplat.strategy import DefaultStrategy

    from thermal_wild_ns.model.strategy import BudgetedDefaultStrategy

    g = torch.Generator().manual_seed(3)
    n = 500
    params = {"means": torch.zeros(n, 3)}
    ours, theirs = (
        cls(absgrad=True, refine_scale2d_stop_iter=100) for cls in (BudgetedDefaultStrategy, DefaultStrategy)
    )
    states = [s.initialize_state() for s in (ours, theirs)]
    for width, height in ((64, 48), (128, 96), (64, 48)):  # accumulates over steps, as in training, at two sizes
        means2d = torch.zeros(1, n, 2)
        means2d.absgrad = torch.rand(1, n, 2, generator=g)
        radii = (torch.rand(1, n, generator=g) * 20).int() * (torch.rand(1, n, generator=g) > 0.4)
        info = {"width": width, "height": height, "n_cameras": 1, "radii": radii, "gaussian_ids": None}
        info["means2d"] = means2d
        for strategy, state in zip((ours, theirs), states):
            strategy._update_state(params, state, info)
    for key in ("grad2d", "count", "radii"):
        assert torch.equal(states[0][key], states[1][key]), key
    assert states[0]["count"].max() > 0


def test_densification_statistics_of_a_split_render_sum_every_ranks_camera():
    """Training across GPUs, a rank's render reports its Gaussians in every rank's camera [W, N]
    (gsplat's distributed meta, n_cameras 1): gradients and counts sum over the cameras as gsplat's
    own statistics do; the screen radius is the largest over them (gsplat's scatter keeps any one)."""
    from gsplat.strategy import DefaultStrategy

    from thermal_wild_ns.model.strategy import BudgetedDefaultStrategy

    g = torch.Generator().manual_seed(4)
    n = 300
    params = {"means": torch.zeros(n, 3)}
    ours, theirs = (
        cls(absgrad=False, refine_scale2d_stop_iter=100) for cls in (BudgetedDefaultStrategy, DefaultStrategy)
    )
    states = [s.initialize_state() for s in (ours, theirs)]
    means2d = torch.zeros(2, n, 2)
    means2d.grad = torch.rand(2, n, 2, generator=g)
    radii = (torch.rand(2, n, generator=g) * 200).int() * (torch.rand(2, n, generator=g) > 0.4)
    info = {"width": 640, "height": 480, "n_cameras": 1, "radii": radii, "gaussian_ids": None, "means2d": means2d}
    for strategy, state in zip((ours, theirs), states):
        strategy._update_state(params, state, info)
    for key in ("grad2d", "count"):
        torch.testing.assert_close(states[0][key], states[1][key])
    assert states[0]["count"].max() == 2
    torch.testing.assert_close(states[0]["radii"], radii.amax(0) / 640.0)


def test_screen_size_rule_is_skipped_where_it_would_split_every_gaussian():
    """At 32x24 (the 1/4 warm-up of a 128x96 camera) the smallest radius a visible Gaussian can
    have, 2 px from rasterization's blur, already exceeds 5 % of 32 px: gsplat's rule then
    marks every visible Gaussian for splitting. Ours records no screen radii there, and still
    does at 64x48, where the rule tells small from large."""
    from gsplat.strategy import DefaultStrategy

    from thermal_wild_ns.model.strategy import BudgetedDefaultStrategy, screen_size_rule_applies
    from thermal_wild_ns.rendering import rasterization

    tiny = torch.tensor([[0.0, 0.0, 2.0], [0.1, 0.0, 2.0]])  # 0.1 mm Gaussians, 2 m away: far below a pixel
    K = torch.tensor([[[16.0, 0.0, 16.0], [0.0, 16.0, 12.0], [0.0, 0.0, 1.0]]])
    _, _, info = rasterization(
        tiny,
        torch.tensor([[1.0, 0, 0, 0]] * 2),
        torch.full((2, 3), 1e-4),
        torch.ones(2),
        torch.ones(2, 1),
        torch.eye(4)[None],
        K,
        32,
        24,
    )
    assert info["radii"].min() == 2  # the floor the rule meets
    assert not screen_size_rule_applies(32, 24, 0.05) and screen_size_rule_applies(64, 48, 0.05)

    n = 4
    params = {"means": torch.zeros(n, 3)}
    for (width, height), recorded in (((32, 24), False), ((64, 48), True)):
        ours, theirs = (
            cls(absgrad=True, refine_scale2d_stop_iter=100) for cls in (BudgetedDefaultStrategy, DefaultStrategy)
        )
        states = [s.initialize_state() for s in (ours, theirs)]
        means2d = torch.zeros(1, n, 2)
        means2d.absgrad = torch.zeros(1, n, 2)  # no gradient: only the screen-size rule could split
        info = {
            "width": width,
            "height": height,
            "n_cameras": 1,
            "radii": torch.full((1, n), 2, dtype=torch.int32),
            "gaussian_ids": None,
            "means2d": means2d,
        }
        for strategy, state in zip((ours, theirs), states):
            strategy._update_state(params, state, info)
        assert bool((states[1]["radii"] > theirs.grow_scale2d).all()) is not recorded  # gsplat: all split at 32 px
        assert bool((states[0]["radii"] > 0).all()) is recorded
        assert not bool((states[0]["radii"] > ours.grow_scale2d).any())  # ours: none split by size


def test_viewer_controls_pick_colormap_and_embedding():
    from thermal_wild_ns.data.palettes import palette_rgb

    model = make_frame_dependent_model()
    camera = make_camera()
    with torch.no_grad():
        out = model.get_outputs(camera)
        level = (out["thermal"].clamp(0, 1)[..., 0] * 255).round().long()
        iron = torch.from_numpy(palette_rgb("iron").astype("float32") / 255)
        assert torch.equal(out["rgb"], iron[level])  # the default colormap
        controls = model.viewer_controls  # the elements ns-viewer shows, as its user sets them
        controls.viewer_colormap.value = "grey"
        assert torch.equal(model.get_outputs(camera)["rgb"][..., 0], level.float() / 255)
        mean_view = model.get_outputs(camera)["thermal"]
        changes = []
        controls.on_state_change(lambda: changes.append(controls.capture_time))
        controls.viewer_time.value = 3.0  # the capture-time slider, at training image 3's position ...
        controls.viewer_time.cb_hook(controls.viewer_time)
        assert controls.capture_time is None and changes == [None]  # ... does nothing while the state is canonical
        controls.viewer_state.value = "capture time"
        controls.viewer_state.cb_hook(controls.viewer_state)
        assert controls.capture_time == 3.0 and changes == [None, 3.0]  # the pipeline updates its colour bar
        assert controls.nearest_training_image() == 3
        frame_view = model.get_outputs(camera)["thermal"]
        assert not torch.equal(frame_view, mean_view)
        # the same state passed as an argument: training image 3's own embedding
        assert torch.equal(
            model.get_outputs(camera, frame_embedding=model.frame_embed.weight[3])["thermal"], frame_view
        )
        controls.viewer_time.value = 3.5  # between two training frames: their average state
        between = model.get_outputs(camera)["thermal"]
        halfway = 0.5 * (model.frame_embed.weight[3] + model.frame_embed.weight[4])
        torch.testing.assert_close(model.get_outputs(camera, frame_embedding=halfway)["thermal"], between)
        # a render that names its state is that state's, whatever the viewer shows
        canonical = model.state_embedding(CANONICAL)
        assert torch.equal(model.get_outputs(camera, frame_embedding=canonical)["thermal"], mean_view)
        controls.viewer_state.value = "canonical"
        assert controls.capture_time is None and torch.equal(model.get_outputs(camera)["thermal"], mean_view)
    assert (
        controls.viewer_state.options == ["canonical", "capture time"]
        and controls.viewer_time.max == model.frame_times[-1] == len(model.frame_times) - 1
    )


def test_world_to_camera_is_splatfactos_view_matrix():
    """gsplat's view matrix: the inverse of the camera-to-world pose with y and z flipped (what
    splatfacto's get_viewmat computes), bit for bit the product form it replaced."""
    from thermal_wild_ns.rendering import world_to_camera

    g = torch.Generator().manual_seed(5)
    q, _ = torch.linalg.qr(torch.randn(3, 3, 3, generator=g))
    c2w = torch.cat([q, torch.randn(3, 3, 1, generator=g)], dim=2)  # [3, 3, 4]
    R = c2w[:, :3, :3] * torch.tensor([1.0, -1.0, -1.0])
    expected = torch.zeros(3, 4, 4)
    expected[:, :3, :3] = R.transpose(1, 2)
    expected[:, :3, 3:4] = -R.transpose(1, 2) @ c2w[:, :3, 3:4]
    expected[:, 3, 3] = 1.0
    viewmat = world_to_camera(c2w)
    assert torch.equal(viewmat, expected)
    pose = torch.cat([c2w, torch.tensor([[[0.0, 0, 0, 1]]]).expand(3, 1, 4)], dim=1)
    flip = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0]))
    assert torch.allclose(viewmat @ pose @ flip, torch.eye(4).expand(3, 4, 4), atol=1e-5)


def test_a_training_view_is_nerfstudios_rescaled_camera_and_leaves_the_camera_alone():
    """At a coarse training resolution the render's intrinsics and size are those of nerfstudio's
    `rescale_output_resolution` (sizes floored: 93 -> 23 at 1/4), the camera object is not
    changed (the datamanager hands the same one again), and a fixed-pose training camera's view
    is computed once per resolution."""
    from thermal_wild_ns.model.camera_views import TrainingViews
    from thermal_wild_ns.rendering import world_to_camera

    views = TrainingViews()
    camera = make_camera(3, width=93, height=61)
    pose = lambda: camera.camera_to_worlds
    before = {name: getattr(camera, name).clone() for name in ("fx", "fy", "cx", "cy", "width", "height")}
    c2w, viewmat, K, W, H, pinhole = views.get(camera, pose, 4, "cpu", cam_idx=3)
    reference = make_camera(3, width=93, height=61)
    reference.rescale_output_resolution(1 / 4)
    assert (W, H) == (int(reference.width), int(reference.height)) == (23, 15)
    assert torch.equal(K[0], reference.get_intrinsics_matrices()[0])
    assert torch.equal(
        torch.tensor(pinhole), torch.cat([reference.fx, reference.fy, reference.cx, reference.cy]).flatten()
    )
    assert torch.equal(viewmat, world_to_camera(camera.camera_to_worlds))
    assert all(torch.equal(getattr(camera, name), value) for name, value in before.items())
    assert views.get(camera, pose, 4, "cpu", cam_idx=3)[1] is viewmat  # kept for this training camera ...
    assert views.get(camera, pose, 1, "cpu", cam_idx=3)[3:5] == (93, 61)  # ... per resolution
    assert views.get(camera, pose, 4, "cpu", cam_idx=None)[1] is not viewmat  # a camera without a fixed pose: computed


def test_a_camera_batchs_sizes_are_read_once_for_all_its_slices_and_again_when_it_changes(monkeypatch):
    """ns-render hands the model `cameras[i : i + 1]` of one batch: every slice gets its own camera's
    sizes and intrinsics (as `host_sizes` reads them), the batch is read to the host once, a batch
    written in place is read again, and a lone camera reads as before."""
    from thermal_wild_ns.model import camera_views

    batch = Cameras(
        camera_to_worlds=torch.eye(4)[:3].expand(5, 3, 4).clone(),
        fx=torch.arange(5.0)[:, None] * 10 + 100.3,
        fy=torch.arange(5.0)[:, None] * 10 + 101.7,
        cx=torch.arange(5.0)[:, None] + 30.1,
        cy=torch.arange(5.0)[:, None] + 20.9,
        width=torch.arange(5)[:, None] + 60,
        height=torch.arange(5)[:, None] + 40,
    )
    order = (3, 0, 4, 1, 2, 3)
    slices = [batch[i : i + 1] for i in order]
    expected = [camera_views.host_sizes(camera) for camera in slices]
    reads = []
    tolist = torch.Tensor.tolist
    monkeypatch.setattr(torch.Tensor, "tolist", lambda self: reads.append(1) or tolist(self))
    sizes = camera_views.CameraSizes()
    for i, camera, their_sizes in zip(order, slices, expected):
        width, height, pinhole = sizes(camera)
        assert (width, height, pinhole) == their_sizes
        assert (width, height) == (60 + i, 40 + i)
    assert len(reads) == 1
    batch.fx.mul_(2.0)  # written in place: read again
    assert sizes(batch[2:3])[2][0] == pytest.approx(2 * 120.3, rel=1e-6)
    lone = make_camera(0, width=93, height=61)
    assert sizes(lone) == camera_views.host_sizes(lone)
    with torch.inference_mode():  # a camera made there has no version to keep it by: read as it is
        made_there = make_camera(0, width=93, height=61)
    assert sizes(made_there) == camera_views.host_sizes(made_there)


def test_baked_background_map_matches_the_mlp_and_is_invalidated():
    """Renders outside training sample the background from a latitude-longitude map of the MLP:
    within 1 % of the background's spread of the MLP itself, at every direction (poles, the
    longitude seam), and rebuilt when the MLP or the embedding changes."""
    model = make_model()
    perturb_output_layers(model)
    embed = model.frame_embed.weight[1].detach()
    g = torch.Generator().manual_seed(4)
    dirs = torch.randn(2000, 3, generator=g)
    dirs = torch.cat([dirs, torch.tensor([[0.0, 0, 1], [0, 0, -1], [-1, 1e-7, 0], [-1, -1e-7, 0]])])
    dirs = dirs / dirs.norm(dim=-1, keepdim=True)  # [P, 3], the seam at longitude +-180 included
    with torch.no_grad():
        exact = model.background_mlp(dirs, embed)[:, 0]  # [P]
        background_map = model.parts.background.baked_map(embed, model.step)
        longitude = torch.atan2(dirs[:, 1], dirs[:, 0]) / torch.pi
        latitude = torch.asin(dirs[:, 2]) / (torch.pi / 2)
        grid = torch.stack([longitude, latitude], dim=-1)[None, None]  # [1, 1, P, 2]
        baked = torch.nn.functional.grid_sample(background_map, grid, align_corners=True)[0, 0, 0]  # [P]
    spread = float(exact.max() - exact.min())
    assert spread > 0 and float((baked - exact).abs().max()) < 0.01 * spread
    assert model.parts.background.baked_map(embed, model.step) is background_map  # cached
    with torch.no_grad():
        model.background_mlp.offset += 0.5  # an in-place edit (a load, an optimizer step) ...
    assert model.parts.background.baked_map(embed, model.step) is not background_map  # ... rebuilds it
    assert model.parts.background.baked_map(
        model.frame_embed.weight[2].detach(), model.step
    ) is not model.parts.background.baked_map(embed, model.step)


def test_renders_outside_training_use_the_baked_background():
    torch.manual_seed(0)  # the output layers' perturbation draws from the global generator
    model = make_model()
    perturb_output_layers(model)
    camera = make_camera(1, width=160, height=128)
    camera.fx[:] = camera.fy[:] = 200.0
    K, c2w = camera.get_intrinsics_matrices()[0], camera.camera_to_worlds[0]
    embed = model.frame_embed.weight[1].detach()
    model.eval()
    with torch.no_grad():
        baked = background(model, K, c2w, embed, 160, 128)
    with torch.enable_grad():
        exact = background(model, K, c2w, embed, 160, 128)  # under autograd: the MLP itself
    spread = float(exact.max() - exact.min())
    assert "background" in model.parts.background.baked.slots
    assert 0 < float((baked - exact.detach()).abs().max()) < 0.01 * spread
    # the view directions: the camera-frame directions of the intrinsics, kept once per intrinsics (given
    # on the host or read from K alike), then rotated: the directions of the full pixel grid
    assert len(model.parts.background._frame_directions.kept) == 1
    with torch.no_grad():
        given = background(model, K, c2w, embed, 160, 128, pinhole=(200.0, 200.0, 80.0, 64.0))
    assert len(model.parts.background._frame_directions.kept) == 1 and torch.equal(given, baked)
    kept = next(iter(model.parts.background._frame_directions.kept.values())) @ c2w[:3, :3].T
    reference = ray_directions(K, c2w, 160, 128, model.config.background_stride)
    assert kept.shape == reference.shape and float((kept - reference).abs().max()) < 1e-6
    outputs = model.get_outputs_for_camera(camera)  # the same object, already on the model's device
    assert torch.equal(outputs["background"], baked)


def test_a_random_training_background_is_redrawn_each_step_and_only_in_training():
    from thermal_wild_ns.errors import InputError

    model = make_model(use_background_mlp=False, use_emission_mlp=False, random_background=True, background_value=0.25)
    camera = make_camera(1)
    K, c2w = camera.get_intrinsics_matrices()[0], camera.camera_to_worlds[0]
    model.train()
    first, second = (background(model, K, c2w, None, 48, 32) for _ in range(2))
    assert first.shape == (32, 48, 1) and torch.all(first == first[0, 0])  # one value over the frame ...
    assert float(first[0, 0]) != float(second[0, 0]) and 0.0 <= float(first[0, 0]) <= 1.0  # ... drawn per step
    outputs = model.get_outputs(camera)  # and what training composites over
    assert torch.isfinite(outputs["rgb"]).all()
    model.eval()
    assert torch.all(background(model, K, c2w, None, 48, 32) == 0.25)  # a render a user sees: the fixed value
    with pytest.raises(InputError, match="random_background needs use_background_mlp False"):
        make_model(random_background=True)


def test_every_option_the_method_offers_is_read_and_the_unused_ones_are_refused(monkeypatch):
    """`ns-train wild-thermal --help` offers a model option only if the model reads it: every field
    of the config is read over a model's life (construction, training steps with densification,
    renders and metrics outside training), or is one of the inherited options it does not use,
    which are hidden from --help and refused by name when set."""
    import dataclasses

    read = set()
    plain = WildThermalModelConfig.__getattribute__

    def recording(config, name):
        read.add(name)
        return plain(config, name)

    monkeypatch.setattr(WildThermalModelConfig, "__getattribute__", recording)
    from types import SimpleNamespace

    model = make_model(refine_every=2, warmup_length=1, stop_split_at=100, reset_alpha_every=2)
    model.train()
    groups = model.get_param_groups()
    optimizers = SimpleNamespace(optimizers={name: torch.optim.Adam(p, lr=1e-3) for name, p in groups.items() if p})
    assert len(model.get_training_callbacks(SimpleNamespace(optimizers=optimizers))) >= 2
    for step in range(6):
        model.step_cb(optimizers, step)  # splatfacto's step callback (what the trainer calls before a step)
        outputs = model.get_outputs(make_camera(step % 5))
        losses = model.get_loss_dict(outputs, {"image": torch.rand(32, 48, 1), "image_idx": step % 5})
        sum(losses.values()).backward()
        model.step_post_backward(step)
        model.zero_grad(set_to_none=True)
    model.eval()
    outputs = model.get_outputs_for_camera(make_camera(0))
    model.get_image_metrics_and_images(outputs, {"image": torch.rand(32, 48, 1)})
    make_model(random_init=True, num_random=50)  # seeded at random: its count and spread
    make_model(view_sh_degree=1)  # a view term and its decision's settings
    fields = {f.name for f in dataclasses.fields(WildThermalModelConfig)} - {"_target"}
    assert fields - read - set(UNUSED_OPTIONS) == set()
    monkeypatch.undo()
    with pytest.raises(InputError, match="does not use use_bilateral_grid.*Remove it"):
        make_model(use_bilateral_grid=True)


def test_emission_for_the_gaussians_in_view_only_renders_the_same():
    """Above `emission_in_view_above` Gaussians the emission MLP runs for those the camera can see
    only: the same training render and the same gradients, with part of the site left out."""
    from thermal_wild_ns.model.in_view import in_view

    renders, grads = [], []
    for above in (10**9, 0):
        torch.manual_seed(0)
        model = make_model(n=400, view_sh_degree=1, emission_in_view_above=above)
        perturb_output_layers(model)
        with torch.no_grad():
            model.gauss_params["means"][::2] += torch.tensor([4.0, 0.0, 0.0])  # half the site out of view
            model.gauss_params["view_sh"].normal_(0, 0.1)
        model.train()
        camera = make_camera(1)
        outputs = model.get_outputs(camera)
        (outputs["thermal"] * torch.linspace(0, 1, 48)).sum().backward()
        renders.append(outputs["thermal"].detach())
        grads.append({n: p.grad.clone() for n, p in model.named_parameters() if p.grad is not None})
    view = model.parts.training_views.get(camera, lambda: camera.camera_to_worlds, 1, model.device, 1)
    seen = in_view(model.means, model.scales, view.viewmat[0], view.K[0], view.width, view.height)
    assert 50 < int(seen.sum()) < 350  # the test leaves Gaussians out, and keeps some
    torch.testing.assert_close(renders[1], renders[0], atol=1e-6, rtol=1e-5)
    assert grads[0].keys() == grads[1].keys()
    for name in grads[0]:
        torch.testing.assert_close(grads[1][name], grads[0][name], atol=1e-6, rtol=1e-4, msg=name)


@pytest.mark.parametrize("cropped", [False, True])
def test_a_fits_views_in_one_rasterization_run_the_emission_for_what_each_camera_sees_and_render_the_same(
    monkeypatch, cropped
):
    """The held-out fits' one pass through one rasterization (a GPU's way; here gsplat's path on the pure-torch
    rasterizer) runs the emission MLP on the Gaussians each camera can see: with half the site out of view, each
    view is `get_outputs`' render at its own state and its gradient reaches its own state alone; also within a
    crop box (the viewer's) that keeps part of what the cameras see."""
    from nerfstudio.data.scene_box import OrientedBox

    import thermal_wild_ns.model.renders as renders
    from thermal_wild_ns.model.in_view import in_view

    monkeypatch.setattr(renders, "resolve_backend", lambda backend, device: "gsplat")
    torch.manual_seed(0)
    model = make_model(n=400, view_sh_degree=1)
    perturb_output_layers(model)
    with torch.no_grad():
        model.gauss_params["means"][::2] += torch.tensor([4.0, 0.0, 0.0])  # half the site out of view
        model.gauss_params["view_sh"].normal_(0, 0.1)
    model.eval()
    if cropped:
        box = OrientedBox(R=torch.eye(3), T=torch.zeros(3), S=torch.full((3,), 1.2))
        model.set_crop(box)
        assert 20 < int(box.within(model.means).sum()) < 200  # the box keeps part of the site
    cameras = [make_camera(1), make_camera(2)]
    with torch.no_grad():
        cameras[1].camera_to_worlds[0, 0, 3] = 0.5  # the second camera a little aside: its own Gaussians
    embeds = model.frame_embed.weight[1:3].detach() + 0.3 * torch.randn(2, model.frame_embed.weight.shape[1])
    with torch.enable_grad():
        each = [
            model.as_recorded(model.get_outputs(c, frame_embedding=e)["thermal"], c)[..., 0].detach()
            for c, e in zip(cameras, embeds)
        ]
    rows, mlp_forward = [], model.emission_mlp.net.forward
    monkeypatch.setattr(model.emission_mlp.net, "forward", lambda x: rows.append(x.shape[0]) or mlp_forward(x))
    leaf = embeds.clone().requires_grad_(True)
    with torch.enable_grad():
        together = model.fitting_views(cameras)(leaf)  # [2, H, W]
        (grad,) = torch.autograd.grad(together[1].sum(), leaf)
    for b in range(2):
        torch.testing.assert_close(together[b].detach(), each[b], atol=1e-5, rtol=1e-5)
    assert grad[1].abs().sum() > 0 and grad[0].abs().sum() == 0
    view = model.parts.training_views.get(cameras[0], lambda: cameras[0].camera_to_worlds, 1, model.device, 1)
    seen = in_view(model.means, model.scales, view.viewmat[0], view.K[0], view.width, view.height)
    assert 50 < int(seen.sum()) < 350  # the test leaves Gaussians out, and keeps some
    assert rows and max(rows) < 2 * 350  # the MLP ran on the pairs drawn, not on both states' every Gaussian


def test_the_view_term_follows_the_view_and_averages_to_nothing():
    """The view-dependent emission: band 1's z coefficient adds +C1 c seen from +z and -C1 c from -z;
    over all directions every band averages to zero (the emission without it is the average)."""
    from thermal_wild_ns.model.view_emission import SH_C1, sh_bands, view_term

    means, coefficients = torch.zeros(1, 3), torch.tensor([[0.0, 0.5, 0.0]])  # [1, 3]: the z band only
    from_above = view_term(means, coefficients, torch.tensor([0.0, 0.0, -5.0]))  # looking along +z
    from_below = view_term(means, coefficients, torch.tensor([0.0, 0.0, 5.0]))
    assert torch.allclose(from_above, torch.tensor([[SH_C1 * 0.5]])) and torch.allclose(from_below, -from_above)
    dirs = torch.nn.functional.normalize(torch.randn(200_000, 3, generator=torch.Generator().manual_seed(0)), dim=-1)
    assert sh_bands(dirs, 2).mean(dim=0).abs().max() < 5e-3


def test_a_model_without_view_term_renders_as_one_with_a_zero_view_term():
    """`view_sh_degree` adds per-Gaussian coefficients, zero at the start: the first render is the
    plain model's; with coefficients it changes with the view, and training reaches them."""
    torch.manual_seed(0)
    plain = make_model()
    torch.manual_seed(0)
    viewed = make_model(view_sh_degree=2)
    assert "view_sh" not in plain.gauss_params and viewed.gauss_params["view_sh"].shape == (400, 8)
    for model in (plain, viewed):
        torch.manual_seed(1)
        perturb_output_layers(model)
        model.train()
    camera = make_camera(1)
    assert torch.equal(plain.get_outputs(camera)["thermal"], viewed.get_outputs(camera)["thermal"])
    outputs = viewed.get_outputs(camera)
    outputs["thermal"].sum().backward()
    assert viewed.gauss_params["view_sh"].grad.abs().sum() > 0
    with torch.no_grad():
        viewed.gauss_params["view_sh"].normal_(0.0, 0.3)
    assert not torch.equal(plain.get_outputs(camera)["thermal"], viewed.get_outputs(camera)["thermal"])
    with pytest.raises(ValueError, match="view_sh_degree must be 0, 1 or 2"):
        make_model(view_sh_degree=3)


def test_the_view_term_trains_through_nerfstudio(tmp_path, demo_scene_dir):
    """With `view_sh_degree`, `ns-train`'s trainer has an optimizer for the coefficients (the method's
    `view_sh` group) and steps them once the term takes part; the full method's default holds it back at
    the demo's budget (below `view_term_above_budget`), so its coefficients stay zero."""
    from thermal_wild_ns.demo import demo_trainer_config
    from thermal_wild_ns.training.trainer import seeded_trainer

    for from_the_start in (True, False):  # the rule off; the method's default rule
        config = demo_trainer_config(tmp_path / str(from_the_start), steps=3, max_gaussians=3000)
        config.pipeline.datamanager.dataparser.data = demo_scene_dir
        config.pipeline.model.view_sh_degree = 1
        assert config.pipeline.model.view_term_above_budget > 3000  # the full method's
        if from_the_start:
            config.pipeline.model.view_term_above_budget = None
        trainer = seeded_trainer(config)
        trainer.train()
        coefficients = trainer.pipeline.model.gauss_params["view_sh"]
        assert "view_sh" in trainer.optimizers.optimizers and bool(coefficients.abs().sum() > 0) == from_the_start
        assert coefficients.shape == (trainer.pipeline.model.num_points, 3)


def test_the_viewer_opens_through_the_nearest_training_camera():
    """Once the viewer started (it hands the control itself), its clients are put just past the
    frustum of the training camera nearest the chosen state (the first for the canonical one)."""
    from types import SimpleNamespace

    model = make_model()
    controls = model.viewer_controls
    controls._look_through_training_camera(0)  # no viewer yet: nothing to move, no error
    client = SimpleNamespace(camera=SimpleNamespace(wxyz=None, position=None), atomic=contextlib.nullcontext)
    frustum = SimpleNamespace(wxyz=(1.0, 0.0, 0.0, 0.0), position=(1.0, 2.0, 3.0))
    controls.viewer_control.viewer = SimpleNamespace(  # what nerfstudio's viewer sets in `_setup`
        camera_handles={0: frustum},
        config=SimpleNamespace(camera_frustum_scale=0.1),
        viser_server=SimpleNamespace(get_clients=lambda: {1: client}),
    )
    controls._look_through_training_camera(controls.nearest_training_image())
    assert client.camera.wxyz == frustum.wxyz
    assert np.allclose(client.camera.position, [1.0, 2.0, 3.2])  # 2 frustum scales along +z (viser's view axis)


def test_a_training_step_resizes_and_checks_its_frame_once(monkeypatch):
    """A training step asks for its frame at the render's size twice (metrics, loss): the frame is
    resized once and both get the same answer a fresh resize gives. The next step of the same frame (the
    same tensor) uses the kept copy (`ResizedFrames`); the same values in another tensor are resized again,
    to the same losses. Outside training every call resizes (nothing is kept between renders there)."""
    model = make_model()
    model.config.num_downscales = 1  # a warm-up step: the frame is resized to the half-size render
    model.train()
    calls = []
    resize = model.get_gt_img
    monkeypatch.setattr(model, "get_gt_img", lambda image: calls.append(tuple(image.shape)) or resize(image))
    outputs = model.get_outputs(make_camera(1))
    assert outputs["thermal"].shape == (16, 24, 1)
    batch = {"image": torch.rand(32, 48, 1), "image_idx": 1}
    losses = model.get_loss_dict(outputs, batch, model.get_metrics_dict(outputs, batch))
    assert calls == [(32, 48, 1)]
    fresh = {key: value for key, value in outputs.items() if key != thermal_loss.GROUND_TRUTH_KEY}
    again = model.get_loss_dict(fresh, batch)
    assert len(calls) == 1 and all(torch.equal(losses[key], again[key]) for key in losses)
    fresh = {key: value for key, value in outputs.items() if key != thermal_loss.GROUND_TRUTH_KEY}
    copied = model.get_loss_dict(fresh, {**batch, "image": batch["image"].clone()})
    assert len(calls) == 2 and all(torch.equal(losses[key], copied[key]) for key in losses)
    model.eval()
    with torch.no_grad():
        outputs = model.get_outputs(make_camera(1))
    model.get_metrics_dict(outputs, batch)
    model.get_metrics_dict(outputs, batch)
    assert len(calls) == 4 and thermal_loss.GROUND_TRUTH_KEY not in outputs


def test_the_view_term_waits_until_the_gaussian_budget_passes_its_threshold():
    """`view_term_above_budget`: below it the term is in no render (training or not) and gets no
    gradient, whatever its coefficients; a budget raise past it, or a start above it, brings it in; the
    trial, where asked, decides instead; a checkpoint whose term was trained renders it."""
    model = make_model(view_sh_degree=2, view_term_above_budget=1000, max_gaussians=800)
    perturb_output_layers(model)
    model.train()
    with torch.no_grad():
        model.gauss_params["view_sh"].normal_(0, 0.5)  # coefficients the rule must leave out
    trained = {k: v.clone() if torch.is_tensor(v) else v for k, v in model.state_dict().items()}
    camera, batch = make_camera(1), {"image": torch.rand(32, 48, 1), "image_idx": 1}

    def render(m):
        return m.get_outputs(camera)["thermal"]

    zeroed = make_model(view_sh_degree=2, view_term_above_budget=1000, max_gaussians=800)
    zeroed.load_state_dict({**trained, "gauss_params.view_sh": torch.zeros_like(trained["gauss_params.view_sh"])})
    zeroed.train()
    assert not model.renders_view_term() and torch.equal(render(model), render(zeroed))
    sum(model.get_loss_dict(model.get_outputs(camera), batch).values()).backward()
    assert model.gauss_params["view_sh"].grad is None
    view = next(d for d in model.decisions() if d.part == "view-dependent emission")
    assert view.choice == "off" and "view_term_above_budget 1,000, the Gaussian budget 800" in view.why
    model.raise_budget(1600)  # the held-back frames ask for more: the term comes in
    assert model.renders_view_term() and not torch.equal(render(model), render(zeroed))
    assert next(d for d in model.decisions() if d.part == "view-dependent emission").choice == "on"
    # a fixed budget above the threshold: the term from the start
    assert make_model(view_sh_degree=2, view_term_above_budget=1000, max_gaussians=2000).renders_view_term()
    # the trial decides where it is on: the budget no longer does
    trial = make_model(view_sh_degree=2, view_term_above_budget=1000, max_gaussians=800)
    trial.try_view_term()
    trial.start_budget(500)
    trial.train()
    trial.step = 1
    assert trial.renders_view_term()
    trial.use_view_term(True)  # its verdict: kept, whatever budget comes after
    trial.raise_budget(900)
    assert trial.renders_view_term()
    # a run's checkpoint whose term was trained (its budget passed the threshold) renders the term when loaded
    loaded = make_model(view_sh_degree=2, view_term_above_budget=1000, max_gaussians=800)
    loaded.load_state_dict(trained)
    loaded.eval()
    assert loaded.renders_view_term()
    assert not zeroed.renders_view_term()  # one whose term never took part has nothing to render


def survey_cameras(xs=(-1.5, -0.75, 0.0, 0.75, 1.5), width=48, height=32):
    """Cameras in a row along x, 3 units above the origin, looking down -z (OpenGL): a strip survey."""
    c2w = torch.eye(4)[None, :3].repeat(len(xs), 1, 1)
    c2w[:, 0, 3] = torch.tensor(xs)
    c2w[:, 2, 3] = 3.0
    n = len(xs)
    return Cameras(
        camera_to_worlds=c2w,
        fx=torch.full((n, 1), 50.0),
        fy=torch.full((n, 1), 50.0),
        cx=torch.full((n, 1), width / 2),
        cy=torch.full((n, 1), height / 2),
        width=width,
        height=height,
    )


def test_the_few_view_mask_takes_a_floater_near_a_camera_and_the_coverages_edge_only_at_any_distance():
    """Of three Gaussians that one camera alone may draw, the one in front of it is a floater; the ground at the
    edge of the strip, seen by one camera from the usual distance, is one only where distance is not asked."""
    from thermal_wild_ns.model.in_view import few_view_mask, frames_seeing
    from thermal_wild_ns.rendering import world_to_camera

    cameras = survey_cameras()
    ground = torch.stack([torch.linspace(-1.0, 1.0, 21), torch.zeros(21), torch.zeros(21)], dim=1)
    floater = torch.tensor([[1.5, 0.0, 2.5]])  # 0.5 in front of the last camera
    edge = torch.tensor([[2.7, 0.0, 0.0]])  # ground beyond the strip's end
    means = torch.cat([ground, floater, edge])  # [23, 3]
    log_scales = torch.full_like(means, float(np.log(0.01)))
    viewmats = world_to_camera(cameras.camera_to_worlds)
    Ks = torch.tensor([[[50.0, 0, 24], [0, 50.0, 16], [0, 0, 1]]]).repeat(5, 1, 1)
    sizes = [(48, 32)] * 5
    counts = frames_seeing(means, log_scales, viewmats, Ks, sizes)
    assert counts[-2] == 1 and counts[-1] == 1 and bool((counts[:-2] >= 2).all())
    centres = cameras.camera_to_worlds[:, :, 3]
    near_only = few_view_mask(means, log_scales, viewmats, Ks, sizes, centres, frames=1, nearer=0.5)
    assert near_only.nonzero().flatten().tolist() == [21]
    anywhere = few_view_mask(means, log_scales, viewmats, Ks, sizes, centres, frames=1, nearer=0.0)
    assert anywhere.nonzero().flatten().tolist() == [21, 22]


def train_on_a_strip(monkeypatch, floater, before_step=None, **overrides):
    """12 training steps of a model over `survey_cameras` with a small Gaussian at `floater` [3] and the rest where
    every camera sees them (`before_step(model, step)`, where given, called before each); the model, the steps
    gsplat grew at and those the few-view prune ran at."""
    from types import SimpleNamespace

    torch.manual_seed(0)  # gsplat's splits draw their new positions
    cameras = survey_cameras()
    model = make_model(n=300, refine_every=2, warmup_length=1, stop_split_at=100, reset_alpha_every=100, **overrides)
    with torch.no_grad():
        model.gauss_params["means"].mul_(0.3)
        model.gauss_params["means"][0] = floater
        model.gauss_params["scales"][0] = float(np.log(0.01))
        model.gauss_params["opacities"].fill_(2.0)  # well above the opacity prune's threshold
    grown, pruned = [], []
    grow, prune_few = model.strategy._grow_gs, model.growth.prune_few_view
    monkeypatch.setattr(model.strategy, "_grow_gs", lambda *a, **k: grown.append(a[-1]) or grow(*a, **k))
    # (state, strategy, params, optimizers, strategy_state, step, views)
    monkeypatch.setattr(model.growth, "prune_few_view", lambda *a: pruned.append(a[5]) or prune_few(*a))
    model.train()
    optimizers = {name: torch.optim.Adam(p, lr=1e-4) for name, p in model.get_param_groups().items() if p}
    model.get_training_callbacks(SimpleNamespace(optimizers=SimpleNamespace(optimizers=optimizers)))
    model.optimizers = optimizers
    for step in range(12):
        model.step = step
        if before_step is not None:
            before_step(model, step)
        camera = cameras[step % 5 : step % 5 + 1]
        camera.metadata = {"cam_idx": step % 5}
        outputs = model.get_outputs(camera)
        losses = model.get_loss_dict(outputs, {"image": torch.rand(32, 48, 1), "image_idx": step % 5})
        sum(losses.values()).backward()
        model.step_post_backward(step)
        for optimizer in optimizers.values():
            optimizer.step()
        model.zero_grad(set_to_none=True)
    return model, grown, pruned


def test_the_few_view_prune_removes_a_floater_at_the_rounds_gsplat_refines_and_says_so(monkeypatch):
    """With `few_view_prune_frames` a Gaussian in front of one training camera goes at densification rounds (the
    steps gsplat grows at, no others), the scene seen by every camera stays, and the run's decisions count it;
    without it the floater stays."""
    floater = torch.tensor([1.5, 0.0, 2.5])  # 0.5 in front of the strip's last camera
    for frames in (0, 1):
        model, grown, pruned = train_on_a_strip(monkeypatch, floater, few_view_prune_frames=frames)
        near_floater = (model.means.detach() - floater).norm(dim=1) < 0.2
        assert grown == [8, 10]  # this schedule's rounds (the pause after the start spares the first ones)
        decided = {d.part: d.choice for d in model.decisions()}
        if frames:
            assert pruned == grown and not bool(near_floater.any())
            assert model.num_points > 250 and int(decided["few-view prune"].split()[1]) >= 1
            resumed = make_model(n=model.num_points, few_view_prune_frames=frames)
            resumed.set_extra_state(model.get_extra_state())  # as a checkpoint's load: the count goes on
            assert resumed.growth_state.few_view_pruned == model.growth_state.few_view_pruned >= 1
        else:
            assert pruned == [] and bool(near_floater.any()) and "few-view prune" not in decided
    with pytest.raises(InputError, match="few_view_prune_frames -1"):
        make_model(few_view_prune_frames=-1)


def test_the_few_view_prune_waits_for_a_gaussian_budget_above_its_threshold(monkeypatch):
    """With `few_view_prune_above_budget` the prune skips the rounds while the budget is at the threshold, the
    floater stays and the decisions say it waits; raised past it between gsplat's two rounds, the budget lets the
    prune in at the second round only, and the floater goes. Across GPUs it stays off."""
    floater = torch.tensor([1.5, 0.0, 2.5])  # 0.5 in front of the strip's last camera
    budget = make_model().strategy.max_gaussians
    waiting, _, pruned = train_on_a_strip(
        monkeypatch, floater, few_view_prune_frames=1, few_view_prune_above_budget=budget
    )
    assert pruned == [] and bool(((waiting.means.detach() - floater).norm(dim=1) < 0.2).any())
    decided = {d.part: (d.choice, d.why) for d in waiting.decisions()}["few-view prune"]
    assert decided[0] == "waits for a larger Gaussian budget" and f"the budget {budget:,}" in decided[1]

    def raise_after_the_first_round(model, step):
        if step == 9:  # gsplat's rounds of this schedule: 8 and 10
            model.raise_budget(budget + 1)

    raised, grown, pruned = train_on_a_strip(
        monkeypatch, floater, raise_after_the_first_round, few_view_prune_frames=1, few_view_prune_above_budget=budget
    )
    assert grown == [8, 10] and pruned == [10]
    assert not bool(((raised.means.detach() - floater).norm(dim=1) < 0.2).any())
    assert {d.part: d.choice for d in raised.decisions()}["few-view prune"].startswith("on: ")
    as_split(raised)  # as a share of the Gaussians across GPUs: the prune stays off, and says so
    assert not raised.growth.few_view_prune_runs(raised.strategy)
    assert {d.part: d.choice for d in raised.decisions()}["few-view prune"].startswith("off across GPUs (")
    with pytest.raises(InputError, match="few_view_prune_above_budget -1"):
        make_model(few_view_prune_above_budget=-1)


def test_only_the_raw_frame_3dgs_variant_prunes_few_view_gaussians_from_the_start():
    """The registered methods: the 3DGS variant on raw frames (no per-frame state, no preprocessing) prunes
    few-view Gaussians at its default budget, with no budget rule; the full method and every other ablation leave
    densification as it is."""
    from thermal_wild_ns.method_configs import METHODS

    pruning = sorted(name for name, spec in METHODS.items() if spec.config.pipeline.model.few_view_prune_frames > 0)
    assert pruning == ["wild-thermal-3dgs"]
    config = METHODS["wild-thermal-3dgs"].config.pipeline.model
    assert (config.few_view_prune_frames, config.few_view_prune_nearer, config.few_view_prune_above_budget) == (
        3,
        0.0,
        None,
    )
    model = make_model(few_view_prune_frames=3)
    assert model.growth.few_view_prune_runs(model.strategy)  # the default budget
    as_split(model)  # a share of the Gaussians across GPUs: off, and said so (not refused)
    assert not model.growth.few_view_prune_runs(model.strategy)
    assert {d.part: d.choice for d in model.decisions()}["few-view prune"] == "off across GPUs"


def test_the_paper_method_is_the_published_full_method_without_this_plugins_additions():
    """`wild-thermal-paper`: the paper's preprocessing on every capture and its model parts, none of the parts this
    plugin added; the training length and growth rules are the full method's."""
    from thermal_wild_ns.method_configs import METHODS

    paper, full = (METHODS[name].config for name in ("wild-thermal-paper", "wild-thermal"))
    preprocessing = paper.pipeline.datamanager.preprocessing
    assert (preprocessing.variant, preprocessing.skip_when_stable) == ("stab+bbhe", False)
    model = paper.pipeline.model
    assert model.use_emission_mlp and model.use_background_mlp and model.heat_aware_ssim
    assert model.alpha_lambda == full.pipeline.model.alpha_lambda > 0
    assert not model.camera_falloff and model.camera_flat_field == 0 and model.view_sh_degree == 0
    assert full.pipeline.model.camera_falloff and full.pipeline.model.view_sh_degree > 0  # what it leaves out
    assert paper.auto_stop == full.auto_stop and model.max_gaussians == full.pipeline.model.max_gaussians
    assert paper.method_name == "wild-thermal-paper"


def test_frames_seeing_counts_in_chunks_of_cameras_what_each_camera_alone_sees(monkeypatch):
    """`frames_seeing` tests the cameras a chunk at a time, each chunk's image sizes its own: the counts are those of
    one camera at a time, however the cameras are chunked."""
    from thermal_wild_ns.model import in_view as module
    from thermal_wild_ns.rendering import world_to_camera

    g = torch.Generator().manual_seed(3)
    means = torch.randn(500, 3, generator=g)
    log_scales = torch.randn(500, 3, generator=g) * 0.5 - 3.0
    cameras = survey_cameras(xs=(-1.2, -0.6, 0.0, 0.4, 0.9, 1.3, 2.0))
    viewmats = world_to_camera(cameras.camera_to_worlds)
    sizes = [(48, 32), (64, 48), (32, 24), (48, 32), (80, 40), (48, 64), (40, 40)]
    Ks = torch.stack([torch.tensor([[50.0, 0, w / 2], [0, 50.0, h / 2], [0, 0, 1]]) for w, h in sizes])
    alone = sum(module.in_view(means, log_scales, viewmats[i], Ks[i], w, h).long() for i, (w, h) in enumerate(sizes))
    assert 0 < int((alone > 0).sum()) < 500 and len(set(alone.tolist())) > 3  # the cameras see different parts
    for elements in (10**9, 1000, 1):  # one chunk, chunks of two cameras, one camera at a time
        monkeypatch.setattr(module, "CAMERA_CHUNK_ELEMENTS", elements)
        assert torch.equal(module.frames_seeing(means, log_scales, viewmats, Ks, sizes), alone)


class StaticBufferRecording(torch.autograd.Function):
    """A CPU stand-in for a CUDA graph of `torch.cuda.make_graphed_callables`: its outputs are one
    buffer per recording and its backward reads the latest call's activations, so a second call
    before the backward overwrites the first's, as a replayed graph does."""

    @staticmethod
    def forward(ctx, recording, *inputs):
        ctx.recording = recording
        with torch.enable_grad():
            for static, value in zip(recording.inputs, inputs):
                static.detach().copy_(value)
            outputs = recording.fn(*recording.inputs)
        recording.outputs = (outputs,) if isinstance(outputs, Tensor) else tuple(outputs)
        if recording.buffers is None:
            recording.buffers = tuple(torch.empty_like(o) for o in recording.outputs)
        for buffer, output in zip(recording.buffers, recording.outputs):
            buffer.copy_(output.detach())
        return tuple(buffer.detach() for buffer in recording.buffers)

    @staticmethod
    def backward(ctx, *grads):
        recording = ctx.recording
        wanted = [t for t in recording.inputs if t.requires_grad]
        found = iter(torch.autograd.grad(recording.outputs, wanted, grads, retain_graph=True, allow_unused=True))
        return (None, *(next(found) if t.requires_grad else None for t in recording.inputs))


class StaticBufferGraph:
    def __init__(self, fn, samples):
        self.fn, self.inputs, self.buffers = fn, samples, None

    def __call__(self, *inputs):
        outputs = StaticBufferRecording.apply(self, *inputs)
        return outputs[0] if len(outputs) == 1 else outputs


@pytest.mark.parametrize("recorded", [False, True], ids=["plain", "graph-like"])
def test_several_cameras_per_step_render_train_and_count_as_their_steps_would(recorded, monkeypatch):
    """`get_training_outputs` of two cameras renders each as `get_outputs` does alone; the step's losses are
    the two steps' means, its gradients the mean of theirs, and the densification statistics those of the
    two steps added (gsplat's scaling by the camera count undoes the mean). `graph-like`: the step's
    recorded pieces (loss, background) replay recordings whose buffers a second call would overwrite,
    as CUDA graphs do: each camera of a step needs recordings of its own."""
    if recorded:
        from thermal_wild_ns.model.graphed import GraphedCalls

        monkeypatch.setattr(GraphedCalls, "records", staticmethod(lambda inputs: True))
        monkeypatch.setattr(GraphedCalls, "_record", staticmethod(StaticBufferGraph))

    def camera(idx, x):
        shifted = make_camera(idx)
        shifted.camera_to_worlds[0, 0, 3] = x
        return shifted

    cameras = [camera(1, 0.0), camera(3, 0.3)]
    batches = [
        {"image": torch.rand(32, 48, 1, generator=torch.Generator().manual_seed(k)), "image_idx": k} for k in (1, 3)
    ]

    def fresh():
        torch.manual_seed(0)  # the same moved output layers and embeddings in both
        return make_frame_dependent_model().train()

    alone, singles = fresh(), []
    for cam, batch in zip(cameras, batches):
        outputs = alone.get_outputs(cam)
        losses = alone.get_loss_dict(outputs, batch)
        (sum(losses.values()) / 2).backward()  # the mean over the two frames
        means2d = alone.info["means2d"]  # each step of its own has its whole loss, not half
        (means2d.absgrad if alone.strategy.absgrad else means2d.grad).mul_(2)
        alone.strategy.update_statistics(alone.gauss_params, alone.strategy_state, alone.info, packed=False)
        singles.append((outputs["thermal"].detach().clone(), {k: v.detach().clone() for k, v in losses.items()}))
    together = fresh()
    outputs = together.get_training_outputs(cameras)
    metrics, losses = together.get_training_metrics_and_losses(outputs, batches)
    sum(losses.values()).backward()
    together.strategy.update_statistics(together.gauss_params, together.strategy_state, together.info, packed=False)

    assert len(outputs) == 2 and together.info["n_cameras"] == 2
    for (thermal, _), out in zip(singles, outputs):
        assert torch.allclose(out["thermal"], thermal, atol=1e-6)
    for key, value in losses.items():
        assert torch.allclose(value, (singles[0][1][key] + singles[1][1][key]) / 2, atol=1e-6), key
    assert metrics["psnr"] > 0 and together.last_training_losses()[1] is None  # no one frame for the guard
    grads = lambda m: {n: p.grad for n, p in m.named_parameters() if p.grad is not None}
    assert grads(alone).keys() == grads(together).keys()
    for name, grad in grads(together).items():
        assert torch.allclose(grad, grads(alone)[name], atol=1e-5, rtol=1e-4), name
    assert together.frame_embed.weight.grad[[1, 3]].abs().sum(-1).gt(0).all()
    for key in ("grad2d", "count"):
        assert torch.allclose(together.strategy_state[key], alone.strategy_state[key], atol=1e-5), key
    assert together.strategy_state["count"].max() == 2  # seen from both cameras


def test_several_cameras_per_step_add_the_step_terms_once():
    """The states' smoothness and the camera optimizer's regulariser belong to the step, not to a camera:
    a step of two cameras computes each once, with the value a step of one has."""
    from nerfstudio.cameras.camera_optimizers import CameraOptimizerConfig

    torch.manual_seed(0)
    model = make_model(state_smoothness=0.5, camera_optimizer=CameraOptimizerConfig(mode="SO3xR3")).train()
    with torch.no_grad():
        model.frame_embed.weight.normal_()  # the states differ: a smoothness term above zero
    calls, residual = [], model.frame_states.neighbour_residual
    model.frame_states.neighbour_residual = lambda: calls.append(1) or residual()
    cameras = [make_camera(1), make_camera(3)]
    batches = [{"image": torch.rand(32, 48, 1), "image_idx": k} for k in (1, 3)]

    one = model.get_loss_dict(model.get_outputs(cameras[0]), batches[0])
    assert len(calls) == 1
    _, two = model.get_training_metrics_and_losses(model.get_training_outputs(cameras), batches)
    assert len(calls) == 2  # once for the step of two cameras
    assert {"state_smoothness", "camera_opt_regularizer"} <= two.keys()
    assert two["state_smoothness"] > 0
    for key in ("state_smoothness", "camera_opt_regularizer"):
        assert torch.equal(two[key], one[key]), key


def test_several_cameras_per_step_need_frames_of_one_size():
    model = make_model()
    model.train()
    with pytest.raises(ValueError, match=r"one size.*\(24, 32\), \(48, 32\)"):
        model.get_training_outputs([make_camera(1), make_camera(2, width=24)])


def test_each_switchable_part_says_what_its_default_rests_on():
    """A run's report says why each part is on or off from the committed runs its default rests on (folders
    that exist), and, where the run's config moved a part off its default, that option and its value."""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    parts = ("emission MLP", "background MLP", "heat-aware SSIM", "alpha regulariser")
    defaults = {d.part: d for d in make_model().decisions()}
    for part in parts:
        why = defaults[part].why
        assert defaults[part].choice == "on" and why.startswith("the default: "), (part, why)
        folders = re.findall(r"docs/results/[\w.-]+", why)
        assert folders and all((root / folder).is_dir() for folder in folders), (part, folders)
    moved = {d.part: d for d in make_model(heat_aware_ssim=False, alpha_lambda=0.0).decisions()}
    assert moved["heat-aware SSIM"].choice == "off"
    assert moved["heat-aware SSIM"].why.startswith("heat_aware_ssim False in this run's config (the default True: ")
    assert moved["alpha regulariser"].why.startswith("alpha_lambda 0.0 in this run's config (the default 0.01: ")
    assert moved["emission MLP"].why == defaults["emission MLP"].why
