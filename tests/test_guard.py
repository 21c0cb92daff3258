"""Training never silently diverges: NaN/inf losses or gradients and loss spikes skip the step,
a broken model stops training with a clear error."""

import pytest
import torch
from demo_trainers import demo_trainer

from thermal_wild_ns.training.divergence import DivergenceGuard, DivergenceGuardConfig, TrainingDiverged


def check_step(guard, loss, parameters, groups, frame=None):
    """Why this step must be skipped, or None: the guard's verdict and its read-back at once."""
    guard.verdict(loss, parameters, groups, frame)
    return guard.settle()


def _trainer(tmp_path, demo_scene_dir, steps, **guard):
    return demo_trainer(tmp_path, demo_scene_dir, steps, "guard", **guard)


def _poison_loss(model, from_step):
    original = model.thermal_loss.forward  # the model's losses, before it records their total for the guard

    def poisoned(*args):
        losses = original(*args)
        if model.training and model.step >= from_step:
            losses["l1_loss"] = losses["l1_loss"] * float("nan")
        return losses

    model.thermal_loss.forward = poisoned


def test_nan_steps_are_skipped_and_leave_the_model_untouched(tmp_path, demo_scene_dir):
    trainer = _trainer(tmp_path, demo_scene_dir, steps=6, max_consecutive_skips=100)
    model = trainer.pipeline.model
    _poison_loss(model, from_step=0)
    before = {k: v.detach().clone() for k, v in model.named_parameters()}
    trainer.train()
    assert trainer.guard.skipped == 6
    for name, param in model.named_parameters():
        assert torch.equal(param, before[name]), name  # no update from a NaN step, no NaN anywhere


def test_a_single_bad_step_is_skipped_and_training_goes_on(tmp_path, demo_scene_dir):
    trainer = _trainer(tmp_path, demo_scene_dir, steps=10)
    model = trainer.pipeline.model
    original = model.thermal_loss.forward

    def one_bad(*args):
        losses = original(*args)
        if model.training and model.step == 4:
            losses["l1_loss"] = losses["l1_loss"] * float("inf")
        return losses

    model.thermal_loss.forward = one_bad
    trainer.train()
    assert trainer.guard.skipped == 1
    assert all(bool(torch.isfinite(p).all()) for p in model.parameters())


def test_persistent_divergence_stops_with_a_clear_error(tmp_path, demo_scene_dir):
    trainer = _trainer(tmp_path, demo_scene_dir, steps=20, max_consecutive_skips=3, max_rollbacks=1)
    _poison_loss(trainer.pipeline.model, from_step=5)
    # each verdict is read back at the next step: steps 5-7 skipped, the third read at step 8 -> back to the
    # state of step 0 (step 8 makes no update); 9-11 skipped again, read at step 12 -> no rollback left: stop
    with pytest.raises(TrainingDiverged, match=r"step 11: 3 steps in a row were skipped \(last: non-finite loss"):
        trainer.train()
    assert trainer.guard.rollbacks == 1


def test_broken_parameters_roll_back_to_the_last_healthy_state(tmp_path, demo_scene_dir):
    trainer = _trainer(tmp_path, demo_scene_dir, steps=16, check_every=5)
    model = trainer.pipeline.model
    original = model.get_loss_dict

    def break_once(outputs, batch, metrics_dict=None):
        if model.training and model.step == 10:
            with torch.no_grad():
                model.gauss_params["means"][:5] = float("nan")  # as a bad update would leave them
        return original(outputs, batch, metrics_dict)

    model.get_loss_dict = break_once
    trainer.train()
    assert trainer.guard.rollbacks == 1  # the check at step 10 found the NaN and went back to step 5's state
    assert all(bool(torch.isfinite(p).all()) for p in model.parameters())
    assert model.num_points > 0 and model.step == 15


def test_loss_spike_and_nan_gradient_detection():
    guard = DivergenceGuard(DivergenceGuardConfig(spike_window=5, loss_spike_factor=10.0))
    param = torch.nn.Parameter(torch.ones(3))
    param.grad = torch.ones(3)
    for _ in range(5):
        assert check_step(guard, torch.tensor(1.0), {"means": [param]}, ["means"]) is None
    assert "loss spike" in check_step(guard, torch.tensor(50.0), {"means": [param]}, ["means"])
    assert check_step(guard, torch.tensor(5.0), {"means": [param]}, ["means"]) is None  # 5x: within the factor
    # a hard frame is not a spike: skipped at its first jump, accepted when it stays there, skipped when it jumps again
    for _ in range(5):
        check_step(guard, torch.tensor(1.0), {"means": [param]}, ["means"], frame=3)
    assert "loss spike" in check_step(guard, torch.tensor(50.0), {"means": [param]}, ["means"], frame=7)
    assert check_step(guard, torch.tensor(60.0), {"means": [param]}, ["means"], frame=7) is None
    assert "loss spike" in check_step(guard, torch.tensor(500.0), {"means": [param]}, ["means"], frame=7)
    param.grad = torch.tensor([1.0, float("nan"), 0.0])
    assert check_step(guard, torch.tensor(1.0), {"means": [param]}, ["means"]) == "non-finite gradient norm in means"


def test_broken_models_are_named(tmp_path, demo_scene_dir):
    trainer = _trainer(tmp_path, demo_scene_dir, steps=1)
    model = trainer.pipeline.model
    guard = trainer.guard
    guard.check_model(model, 0)  # a healthy model passes
    with torch.no_grad():
        model.gauss_params["opacities"].fill_(-30.0)
    with pytest.raises(TrainingDiverged, match="scene has turned transparent"):
        guard.check_model(model, 100)
    with torch.no_grad():
        model.gauss_params["means"][0, 0] = float("nan")
    with pytest.raises(TrainingDiverged, match=r"step 200: parameter 'gauss_params.means' holds NaN/inf"):
        guard.check_model(model, 200)


def test_scheduled_loss_jumps_rebaseline_instead_of_skipping(tmp_path, demo_scene_dir):
    """An opacity reset or a finer resolution moves every frame's loss at once: the guard must take a
    new baseline there, not skip each frame's first visit (the stress runs skipped ~30 steps per reset)."""
    guard = DivergenceGuard(DivergenceGuardConfig(spike_window=5, loss_spike_factor=10.0))
    for frame in range(5):
        assert check_step(guard, torch.tensor(0.01), {}, [], frame) is None
    assert check_step(guard, torch.tensor(0.5), {}, [], 0) is not None  # a jump is a spike...
    guard.rebaseline()
    assert check_step(guard, torch.tensor(0.5), {}, [], 1) is None  # ...unless the schedule moved the loss

    model = _trainer(tmp_path, demo_scene_dir, steps=1).pipeline.model
    reset, stop, r = model.strategy.reset_every, model.strategy.refine_stop_iter, model.config.resolution_schedule
    moves = {step for step in range(1, 3 * max(reset, r) + 2) if model.schedule_moves_loss(step)}
    expected = {s + 1 for s in range(reset, stop + 1, reset)} | {
        k * r for k in range(1, model.config.num_downscales + 1)
    }
    assert moves == {s for s in expected if s < 3 * max(reset, r) + 2}
    assert not model.schedule_moves_loss(1) and not model.schedule_moves_loss(2)


def test_the_lean_step_gives_way_to_nerfstudios_where_it_cannot_stand_in(tmp_path, demo_scene_dir):
    """Gradient clipping is one of nerfstudio's step's options the lean step leaves out: with it
    set, training runs nerfstudio's step and says which optimizer made it so."""
    from thermal_wild_ns.demo import demo_trainer_config
    from thermal_wild_ns.training.trainer import seeded_trainer

    config = demo_trainer_config(tmp_path, steps=4, max_gaussians=3000)
    config.pipeline.datamanager.dataparser.data = demo_scene_dir
    config.optimizers["opacities"]["optimizer"].max_norm = 1.0
    trainer = seeded_trainer(config)
    from thermal_wild_ns.training.lean_step import lean_step_unsupported

    assert not trainer.lean and "'opacities'" in lean_step_unsupported(trainer.config, trainer.optimizers)
    before = trainer.pipeline.model.opacities.detach().clone()
    trainer.train()
    assert not torch.equal(trainer.pipeline.model.opacities, before)  # it trained, through nerfstudio's step


def test_a_large_snapshot_goes_to_host_memory(monkeypatch):
    """The guard's healthy copy and the automatic stop's best one stay on the GPU while small next to
    the memory it has left, and go to the host when large (a survey's Gaussians would be held twice)."""
    from thermal_wild_ns.training import checkpoints

    gpu = torch.device("cuda")
    monkeypatch.setattr(torch.cuda, "mem_get_info", lambda device: (8 * 2**30, 80 * 2**30))
    monkeypatch.setattr(torch.cuda, "memory_reserved", lambda device: 10 * 2**30)
    monkeypatch.setattr(torch.cuda, "memory_allocated", lambda device: 10 * 2**30)
    assert checkpoints.snapshot_device(1 * 2**30, gpu) == gpu  # an eighth of the 8 GiB left
    assert checkpoints.snapshot_device(3 * 2**30, gpu) == torch.device("cpu")
    assert checkpoints.snapshot_device(3 * 2**30, torch.device("cpu")) == torch.device("cpu")
    state = {"a": torch.ones(3), "rng": torch.get_rng_state(), "nested": [torch.zeros(2)], "n": 4}
    copied = checkpoints._copied(state, torch.device("cpu"))
    assert copied["n"] == 4 and torch.equal(copied["rng"], state["rng"])
    assert copied["a"].data_ptr() != state["a"].data_ptr() and torch.equal(copied["nested"][0], state["nested"][0])


def test_a_step_out_of_gpu_memory_rolls_back_and_caps_growth(tmp_path, demo_scene_dir):
    """A step that runs out of GPU memory (raised here on CPU as torch raises it) goes back to the last
    healthy state, whose Gaussian count becomes the most densification may reach; the run goes on."""
    trainer = _trainer(tmp_path, demo_scene_dir, steps=12, check_every=5)
    model = trainer.pipeline.model
    original = model.get_loss_dict

    def out_of_memory_once(outputs, batch, metrics_dict=None):
        if model.training and model.step == 8:
            raise torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 7.63 GiB.")
        return original(outputs, batch, metrics_dict)

    model.get_loss_dict = out_of_memory_once
    load = model.load_state_dict
    held_at_restore = []

    def recording_load(state, *args, **kwargs):  # what the model still holds when the healthy copy arrives
        held_at_restore.append(model.num_points)
        return load(state, *args, **kwargs)

    model.load_state_dict = recording_load
    trainer.train()
    # the failed state's Gaussians were let go first: where memory ran out, both copies do not fit
    assert held_at_restore == [0]
    healthy = trainer._healthy  # step 10's, made after the rollback to step 5's
    assert trainer.guard.rollbacks == 1 and model.step == 11
    assert model.strategy.max_gaussians < 3000  # the demo's budget, lowered to the count of step 5
    assert model.num_points <= model.strategy.max_gaussians
    assert healthy is not None and healthy["step"] == 10


def test_out_of_gpu_memory_with_no_rollback_left_says_what_to_do(tmp_path, demo_scene_dir):
    trainer = _trainer(tmp_path, demo_scene_dir, steps=8, check_every=5, max_rollbacks=0)
    model = trainer.pipeline.model

    def out_of_memory(outputs, batch, metrics_dict=None):
        raise torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 7.63 GiB.")

    model.get_loss_dict = out_of_memory
    with pytest.raises(SystemExit, match="out of GPU memory.*max-gaussians.*multi_gpu"):
        trainer.train()


def test_the_verdict_is_decided_on_the_device_and_read_back_at_the_next_step():
    """`verdict` returns a tensor the optimizer reads where it lives; the skip is counted and said when
    the next step's verdict (or `settle`) reads the values back; a hard frame's threshold holds on the
    device as on the host."""
    guard = DivergenceGuard(DivergenceGuardConfig(spike_window=3, loss_spike_factor=10.0, max_consecutive_skips=2))
    param = torch.nn.Parameter(torch.ones(3))
    param.grad = torch.ones(3)
    for step in range(3):
        accepted = guard.verdict(torch.tensor(1.0), {"means": [param]}, ["means"], frame=step, step=step)
        assert isinstance(accepted, torch.Tensor) and accepted.dtype == torch.bool and bool(accepted)
    assert guard.spike_threshold(9) == (float("inf"), None)  # the third loss is not read back yet
    assert guard.settle() is None and guard.spike_threshold(9) == (10.0, 1.0)  # now the window is full
    accepted = guard.verdict(torch.tensor(50.0), {"means": [param]}, ["means"], frame=5, step=3)
    assert not bool(accepted) and guard.skipped == 0  # decided; not yet read back
    accepted = guard.verdict(torch.tensor(60.0), {"means": [param]}, ["means"], frame=5, step=4)
    assert guard.skipped == 1 and bool(accepted)  # step 3 counted; frame 5 was at 50 last time: a hard frame
    param.grad = torch.tensor([1.0, float("inf"), 0.0])
    guard.verdict(torch.tensor(1.0), {"means": [param]}, ["means"], frame=6, step=5)
    assert guard.settle() == "non-finite gradient norm in means" and guard.skipped == 2
    assert guard.settle() is None  # nothing pending
    guard.verdict(torch.tensor(float("nan")), {"means": [param]}, ["means"], step=6)
    with pytest.raises(TrainingDiverged, match=r"step 6: 2 steps in a row were skipped \(last: non-finite loss"):
        guard.settle()


VERDICT_CASES = [  # (loss or None, each gradient or None, the losses before it)
    (1.0, [[1.0, 2.0], [3.0]], []),
    (float("nan"), [[1.0, 2.0], [3.0]], []),
    (float("inf"), [[1.0, 2.0], [3.0]], []),
    (-float("inf"), [[1.0, 2.0], [3.0]], []),
    (-1.0, [[1.0, 2.0], [3.0]], []),
    (1.0, [[1.0, float("nan")], [3.0]], []),
    (1.0, [[1.0, 2.0], [-float("inf")]], []),
    (1.0, [[2e38], [2e38]], []),  # every gradient finite: on a CPU every norm too, their sum not
    (1.0, [[0.0, -0.0], None], []),
    (None, [[1.0], [float("nan")]], []),
    (None, [[1.0], [2.0]], []),
    (5.0, None, []),
    (float("nan"), None, []),
    (50.0, [[1.0], [2.0]], [1.0, 1.0, 1.0]),  # a spike
    (9.0, [[1.0], [2.0]], [1.0, 1.0, 1.0]),  # below it
    (float("inf"), [[1.0], [2.0]], [1.0, 1.0, 1.0]),
]


def verdicts_match_the_reference(device: str) -> None:
    """The guard's verdict on `device`, on every case of VERDICT_CASES, against the checks it stands for
    computed plainly on the host (the loss and the gradient norms summing to a finite float32: each finite and
    no overflow; the loss at most the spike threshold), and the values it reads back (the reason, the recorded
    losses)."""
    for loss, grads, history in VERDICT_CASES:
        guard = DivergenceGuard(DivergenceGuardConfig(spike_window=3, loss_spike_factor=10.0))
        for previous in history:
            guard.recent.append(previous)
        params = [torch.nn.Parameter(torch.zeros(len(g) if g else 1, device=device)) for g in grads or [None]]
        for param, grad in zip(params, grads or [None]):
            param.grad = None if grad is None else torch.tensor(grad, device=device)
        loss_tensor = None if loss is None else torch.tensor(loss, device=device)
        threshold, _ = guard.spike_threshold(None)
        norms = [torch.linalg.vector_norm(p.grad.double().cpu()) for p in params if p.grad is not None]
        summed = ([] if loss is None else [torch.tensor(loss, dtype=torch.float64)]) + norms
        expected = [] if loss is None else [torch.tensor(loss) <= threshold]
        if summed:
            expected.append(torch.isfinite(torch.stack(summed).float().sum()))
        accepted = guard.verdict(loss_tensor, {"g": params}, ["g"])
        if not expected:
            assert accepted is None
            continue
        case = (loss, grads, history)
        assert accepted.device.type == torch.device(device).type and accepted.dtype == torch.bool, case
        assert bool(accepted) == all(bool(e) for e in expected), case
        reason = guard.settle()
        assert (reason is None) == bool(accepted), case
        if grads == [[2e38], [2e38]]:  # every value finite: the reason read back says why
            # a CPU's norm rescales (each norm finite, their sum not); a GPU's squares overflow (each norm inf)
            device_norms = torch._foreach_norm([p.grad for p in params])
            if all(bool(torch.isfinite(n)) for n in device_norms):
                assert reason == "the loss and gradient norms overflow float32 (each finite)", case
            else:
                assert reason == "non-finite gradient norm in g", case
        if loss is not None and torch.isfinite(torch.tensor(loss)) and bool(accepted):
            assert guard.recent[-1] == loss, case


def test_the_verdict_is_the_checks_it_stands_for():
    verdicts_match_the_reference("cpu")


def test_a_rejected_step_leaves_the_densification_statistics_as_they_were():
    """The guard's device verdict reaches the statistics: a rejected step's gradients are masked out
    (the plugin's masked sums, and gsplat's own for a packed render), an accepted one's are counted."""
    from types import SimpleNamespace

    from test_model import make_camera, make_model

    model = make_model()
    model.train()
    groups = model.get_param_groups()
    optimizers = SimpleNamespace(optimizers={name: torch.optim.Adam(p, lr=1e-3) for name, p in groups.items() if p})
    for step, (accepted, counted) in enumerate(((torch.tensor(False), False), (torch.tensor(True), True)), start=1):
        model.step_cb(optimizers, step)  # as the trainer does before a step
        outputs = model.get_outputs(make_camera(1))
        losses = model.get_loss_dict(outputs, {"image": torch.rand(32, 48, 1), "image_idx": 1})
        sum(losses.values()).backward()
        before = {k: v.clone() for k, v in model.strategy_state.items() if isinstance(v, torch.Tensor)}
        model.weigh_step_statistics(accepted)
        model.step_post_backward(model.step)
        count = model.strategy_state["count"]
        assert (count is not None and bool((count > before.get("count", torch.zeros_like(count))).any())) == counted
        model.zero_grad(set_to_none=True)
    strategy, state = model.strategy, model.strategy_state
    means2d = torch.zeros(3, 2, requires_grad=True)
    means2d.sum().backward()
    packed = {"gaussian_ids": torch.tensor([0, 0, 2]), "radii": torch.tensor([3, 5, 4]), "means2d": means2d}
    info = {**packed, "width": 100, "height": 50, "n_cameras": 1, "accepted": torch.tensor(False)}
    counts = state["count"].clone()
    strategy._update_state(model.gauss_params, state, info, packed=True)  # gsplat's own sums
    assert torch.equal(state["count"], counts)
