"""Parity of the pure-torch rasterizer with gsplat's CUDA kernels (needs a CUDA GPU; skipped elsewhere).

Random scenes of ~1k Gaussians at 128x96: images, alphas, and the gradients of every input and
of means2d (grad and absgrad, which densification reads) must agree. The measured errors are
written to $PARITY_OUT (JSON) when set; docs/results/gpu_parity.json holds the committed device run.
"""

import functools
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch
from conftest import random_scene

from thermal_wild_ns.rendering import rasterization

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA for gsplat's kernels")

IMAGE_ATOL = 1e-4
GRAD_RTOL = 1e-3


def _render_and_grads(backend, scene, width, height, weights):
    inputs = [t.clone().requires_grad_() for t in scene[:5]]
    image, alphas, meta = rasterization(
        *inputs, *scene[5:], width, height, packed=False, absgrad=True, render_mode="RGB+ED", backend=backend
    )
    meta["means2d"].retain_grad()
    ((image[..., :1] * weights).sum() + 0.1 * image[..., 1:].sum() + alphas.sum()).backward()
    grads = {name: t.grad for name, t in zip(("means", "quats", "scales", "opacities", "colors"), inputs)}
    grads["means2d"] = meta["means2d"].grad
    grads["means2d_absgrad"] = meta["means2d"].absgrad
    return image, alphas, meta["radii"], grads


def _gradients(module: torch.nn.Module) -> list:
    """Copies of each parameter's gradient, a packed MLP's split into its layers' weights and biases: each
    compared on its own scale, as when they were tensors of their own."""
    from thermal_wild_ns.model.fields import PackedMLP

    grads = []
    for name, parameter in module.named_parameters():
        owner = module.get_submodule(name.rpartition(".")[0])
        if isinstance(owner, PackedMLP):
            grads += [t.clone() for layer in owner.layers(parameter.grad) for t in layer]
        else:
            grads.append(parameter.grad.clone())
    return grads


def _relative(a, b):
    """Error relative to the gradient's scale: max |a - b| / max |b|, and ||a - b|| / ||b||."""
    return float((a - b).abs().max() / b.abs().max().clamp(min=1e-12)), float(
        (a - b).norm() / b.norm().clamp(min=1e-12)
    )


def test_torch_backend_matches_gsplat():
    width, height = 128, 96
    report = {"width": width, "height": height, "scenes": []}
    for seed in range(5):
        scene = random_scene(1000, width, height, seed=seed, device="cuda")
        weights = torch.rand(1, height, width, 1, device="cuda", generator=torch.Generator("cuda").manual_seed(seed))
        ref = _render_and_grads("gsplat", scene, width, height, weights)
        ours = _render_and_grads("torch", scene, width, height, weights)
        entry = {
            "seed": seed,
            "radii_equal": bool(torch.equal(ref[2], ours[2])),
            "image_max_abs": float((ref[0][..., :1] - ours[0][..., :1]).abs().max()),
            "depth_max_abs": float((ref[0][..., 1:] - ours[0][..., 1:]).abs().max()),
            "alpha_max_abs": float((ref[1] - ours[1]).abs().max()),
            "grads": {k: _relative(ours[3][k], ref[3][k]) for k in ref[3]},
        }
        report["scenes"].append(entry)
    report["worst"] = {
        "image_max_abs": max(s["image_max_abs"] for s in report["scenes"]),
        "alpha_max_abs": max(s["alpha_max_abs"] for s in report["scenes"]),
        "grad_max_rel": max(v[0] for s in report["scenes"] for v in s["grads"].values()),
        "grad_norm_rel": max(v[1] for s in report["scenes"] for v in s["grads"].values()),
    }
    print(json.dumps(report, indent=1))
    if os.environ.get("PARITY_OUT"):
        with open(os.environ["PARITY_OUT"], "w") as f:
            json.dump(report, f, indent=1)
    for s in report["scenes"]:
        assert s["radii_equal"]
        assert s["image_max_abs"] <= IMAGE_ATOL and s["alpha_max_abs"] <= IMAGE_ATOL
        for name, (max_rel, norm_rel) in s["grads"].items():
            assert norm_rel <= GRAD_RTOL, (s["seed"], name, max_rel, norm_rel)


def test_a_view_rendered_through_gsplats_cuda_functions_equals_gsplats_rasterization():
    """`render_one_view` (outside training, on gsplat: its CUDA functions called directly) gives gsplat's
    `rasterization`'s render and alpha bit for bit, both rasterize modes, at three sizes."""
    from thermal_wild_ns.rendering import FAR_PLANE, NEAR_PLANE, render_one_view

    for seed, (width, height) in enumerate([(128, 96), (640, 512), (97, 61)]):
        means, quats, scales, opacities, colors, viewmat, K = random_scene(
            3000, width, height, seed=seed, device="cuda"
        )
        for mode in ("classic", "antialiased"):
            with torch.no_grad():
                image, alpha, _ = rasterization(
                    means,
                    quats,
                    scales,
                    opacities,
                    colors,
                    viewmat,
                    K,
                    width,
                    height,
                    packed=False,
                    near_plane=NEAR_PLANE,
                    far_plane=FAR_PLANE,
                    render_mode="RGB+ED",
                    rasterize_mode=mode,
                    backend="gsplat",
                )
                ours = render_one_view(
                    means, quats, scales, opacities, colors, viewmat, K, width, height, mode, "gsplat"
                )
            assert ours[0].shape == image.shape == (1, height, width, 2) and ours[1].shape == alpha.shape
            assert torch.equal(ours[0], image) and torch.equal(ours[1], alpha), (seed, mode)
            assert float(alpha.max()) > 0.5  # the scene is in view


def _training_render(rasterize, scene, width, height, weights, **options):
    """A render of `rasterize` with autograd: (render, alpha, meta, gradients of the Gaussians and of means2d)."""
    inputs = [t.clone().requires_grad_() for t in scene[:5]]
    render, alpha, meta = rasterize(*inputs, *scene[5:], width, height, **options)
    meta["means2d"].retain_grad()
    ((render * weights).sum() + alpha.square().sum()).backward()
    grads = {name: t.grad for name, t in zip(("means", "quats", "scales", "opacities", "colors"), inputs)}
    grads["means2d"], grads["means2d_absgrad"] = meta["means2d"].grad, meta["means2d"].absgrad
    return render, alpha, meta, grads


def test_a_training_render_through_gsplats_functions_is_gsplats_rasterization():
    """`rasterize_unpacked` (a training step's render on one GPU: gsplat's autograd functions and CUDA calls
    directly) gives gsplat's `rasterization`'s render, alpha and meta exactly, and its gradients (those of
    means2d, which densification reads, among them) up to the order of gsplat's atomic sums: one and two
    cameras, with and without the depth channel, both rasterize modes, two sizes."""
    from thermal_wild_ns.rendering import FAR_PLANE, NEAR_PLANE, rasterize_unpacked

    cases = [(1, True, "classic"), (1, False, "antialiased"), (2, False, "classic"), (2, True, "antialiased")]
    for seed, (width, height) in enumerate([(128, 96), (97, 61)]):
        scene = random_scene(2000, width, height, seed=seed, device="cuda")
        for cameras, with_depth, mode in cases:
            viewmats, Ks = scene[5].repeat(cameras, 1, 1), scene[6].repeat(cameras, 1, 1)
            viewmats[1:, 0, 3] += 0.1  # a second camera beside the first
            views = [*scene[:5], viewmats, Ks]
            channels = 2 if with_depth else 1
            weights = torch.rand(cameras, height, width, channels, device="cuda")
            reference = _training_render(
                rasterization,
                views,
                width,
                height,
                weights,
                packed=False,
                near_plane=NEAR_PLANE,
                far_plane=FAR_PLANE,
                render_mode="RGB+ED" if with_depth else "RGB",
                absgrad=True,
                rasterize_mode=mode,
                backend="gsplat",
            )
            ours = _training_render(
                rasterize_unpacked,
                views,
                width,
                height,
                weights,
                with_depth=with_depth,
                absgrad=True,
                rasterize_mode=mode,
                backend="gsplat",
            )
            case = (seed, cameras, with_depth, mode)
            assert ours[0].shape == reference[0].shape == (cameras, height, width, channels), case
            assert torch.equal(ours[0], reference[0]) and torch.equal(ours[1], reference[1]), case
            assert float(reference[1].max()) > 0.5, case  # the scene is in view
            drawn = reference[2]["radii"] > 0  # [C, N]: a culled Gaussian's projected values are never written
            assert torch.equal(ours[2]["radii"], reference[2]["radii"]) and bool(drawn.any()), case
            for key in ("means2d", "depths", "conics", "opacities"):
                assert torch.equal(ours[2][key][drawn], reference[2][key][drawn]), (case, key)
            for key in ("isect_ids", "flatten_ids"):
                assert torch.equal(ours[2][key], reference[2][key]), (case, key)
            for key in ("width", "height", "n_cameras", "tile_width", "tile_height", "tile_size"):
                assert ours[2][key] == reference[2][key], (case, key)
            for name, grad in reference[3].items():
                assert float(grad.abs().max()) > 0, (case, name)  # a gradient that reached every input
                assert _relative(ours[3][name], grad)[0] <= 1e-5, (case, name, _relative(ours[3][name], grad))


def test_a_render_replayed_as_cuda_graphs_equals_the_one_it_recorded():
    """Outside training the model replays the pieces around gsplat as CUDA graphs
    (`rendering/captured.py`): each render equals the same render run kernel by kernel, for
    cameras of two sizes in turn and a change of state, and an earlier render's outputs are not
    overwritten by a later replay; a graph's output passed to another graph is copied at every
    replay (it changes without a new tensor version)."""
    from test_model import make_camera, make_model, perturb_output_layers

    torch.manual_seed(0)
    model = make_model().cuda()
    perturb_output_layers(model)
    model.eval()
    turned = make_camera(3, width=160, height=128)  # the first camera's size, turned: another background
    angle = torch.tensor(0.4)
    turned.camera_to_worlds[0, :3, :3] = torch.tensor(
        [[angle.cos(), 0.0, angle.sin()], [0.0, 1.0, 0.0], [-angle.sin(), 0.0, angle.cos()]]
    )
    cameras = [make_camera(1, width=160, height=128), turned, make_camera(2, width=96, height=64)]
    eager = make_model().cuda()
    eager.load_state_dict(model.state_dict())
    eager.eval()
    eager.parts.captured = lambda key, fn, *inputs, copy_outputs=False: fn(*inputs)  # kernel by kernel
    with torch.no_grad():
        first = model.get_outputs_for_camera(cameras[0].to("cuda"))
        kept = {name: value.clone() for name, value in first.items()}
        for round_ in range(3):
            state = None if round_ < 2 else model.frame_embed.weight[3]
            for camera in cameras:
                camera = camera.to("cuda")
                replayed = model.get_outputs_for_camera(camera, frame_embedding=state)
                reference = eager.get_outputs(camera, state)
                for name, value in reference.items():
                    assert torch.equal(replayed[name], value), (round_, name)
    assert len(model.parts.captured.graphs) == 4  # two sizes, each a view and a finishing graph
    assert all(torch.equal(first[name], kept[name]) for name in kept)
    with torch.no_grad():  # the turned camera sees another background: a stale copy would show
        assert not torch.equal(model.get_outputs_for_camera(turned.to("cuda"))["background"], first["background"])
    # another thread (the viewer's) renders through graphs of its own
    import threading

    from_thread = {}

    def render_in_thread():
        with torch.no_grad():
            from_thread.update(model.get_outputs_for_camera(turned.to("cuda")))

    worker = threading.Thread(target=render_in_thread)
    worker.start()
    worker.join()
    with torch.no_grad():
        reference = eager.get_outputs(turned.to("cuda"))
    assert len(model.parts.captured.per_thread) == 2 and len(model.parts.captured.graphs) == 4
    assert all(torch.equal(from_thread[name], value) for name, value in reference.items())


def test_the_loss_replayed_as_cuda_graphs_equals_the_loss_run_kernel_by_kernel():
    """A training step's loss terms through `GraphedCalls` (forward and backward replayed): the same
    terms and the same gradients as kernel by kernel, for frames of two sizes in turn, each size's
    graphs recorded once."""
    from thermal_wild_ns.model.thermal_loss import ThermalLoss
    from thermal_wild_ns.model.wild_thermal import WildThermalModelConfig

    graphed = ThermalLoss(WildThermalModelConfig(graphed_loss=True), None)
    eager = ThermalLoss(WildThermalModelConfig(graphed_loss=False), None)
    generator = torch.Generator("cuda").manual_seed(0)
    for step in range(6):
        height, width = (64, 80) if step % 2 else (128, 160)
        frame = torch.rand(height, width, 1, device="cuda", generator=generator)
        render, alpha, background = (torch.rand_like(frame) for _ in range(3))
        results = []
        for loss in (graphed, eager):
            pred, accumulation = render.clone().requires_grad_(), alpha.clone().requires_grad_()
            outputs = {"thermal": pred * 1.0, "accumulation": accumulation * 1.0, "background": background}
            gt, contrast = loss.ground_truth(frame, outputs["thermal"], image=step % 3)
            terms = loss(outputs, gt, contrast, image=step % 3)
            sum(terms.values()).backward()
            results.append(({k: v.detach().clone() for k, v in terms.items()}, pred.grad, accumulation.grad))
        (graphed_terms, *graphed_grads), (eager_terms, *eager_grads) = results
        assert graphed_terms.keys() == eager_terms.keys() == {"l1_loss", "ssim_loss", "alpha_loss"}
        for name in eager_terms:
            assert torch.allclose(graphed_terms[name], eager_terms[name], rtol=1e-6, atol=0), (step, name)
        for ours, reference in zip(graphed_grads, eager_grads):
            assert torch.allclose(ours, reference, rtol=1e-5, atol=1e-9), step
    assert len(graphed.graphed.graphs) == 2 and all(graphs is not None for graphs in graphed.graphed.graphs.values())


def test_two_cameras_of_one_step_replay_graphs_of_their_own():
    """Two frames' loss terms through `GraphedCalls` before one backward (several cameras per step):
    each camera's slot replays its own recording, so the second call overwrites none of the first's
    outputs or activations: terms and gradients as kernel by kernel."""
    from thermal_wild_ns.model.thermal_loss import ThermalLoss
    from thermal_wild_ns.model.wild_thermal import WildThermalModelConfig

    graphed = ThermalLoss(WildThermalModelConfig(graphed_loss=True), None)
    eager = ThermalLoss(WildThermalModelConfig(graphed_loss=False), None)
    generator = torch.Generator("cuda").manual_seed(0)
    frames = [torch.rand(64, 80, 1, device="cuda", generator=generator) for _ in range(2)]
    renders = [torch.rand_like(frame) for frame in frames]
    results = []
    for loss in (graphed, eager):
        for _ in range(2):  # the first records, the second replays
            preds = [render.clone().requires_grad_() for render in renders]
            terms = []
            for slot, (frame, pred) in enumerate(zip(frames, preds)):
                outputs = {"thermal": pred * 1.0, "accumulation": pred * 0.5, "background": frame * 0.0}
                gt, contrast = loss.ground_truth(frame, outputs["thermal"], image=slot)
                terms.append(loss(outputs, gt, contrast, image=slot, slot=slot))
            sum(sum(t.values()) for t in terms).backward()
        results.append(([{k: v.detach().clone() for k, v in t.items()} for t in terms], [p.grad for p in preds]))
    (graphed_terms, graphed_grads), (eager_terms, eager_grads) = results
    for ours, reference in zip(graphed_terms, eager_terms):
        for name in reference:
            assert torch.allclose(ours[name], reference[name], rtol=1e-6, atol=0), name
    assert not torch.equal(eager_terms[0]["l1_loss"], eager_terms[1]["l1_loss"])  # two frames, two answers
    for ours, reference in zip(graphed_grads, eager_grads):
        assert torch.allclose(ours, reference, rtol=1e-5, atol=1e-9)
    assert sorted(key[0] for key in graphed.graphed.graphs) == [0, 1]


@pytest.mark.parametrize("coupling", ["affine", "mlp"])
def test_the_background_mlp_replayed_as_cuda_graphs_equals_it_run_kernel_by_kernel(coupling):
    """Training renders' background through `GraphedCalls` (`graphed_background`): the same background
    and the same gradients of the MLP's parameters and of the frame embedding as kernel by kernel,
    for frames of two sizes in turn, with the parameters changed in place between steps (as Adam
    does: a replay reads them where they live)."""
    from thermal_wild_ns.model.background import ThermalBackground
    from thermal_wild_ns.model.fields import BackgroundMLP
    from thermal_wild_ns.model.wild_thermal import WildThermalModelConfig

    torch.manual_seed(0)
    mlp = BackgroundMLP(frame_dim=8, frame_coupling=coupling).cuda()
    for parameter in mlp.parameters():  # the zero-initialised output layer would give zero gradients upstream
        parameter.data.normal_(0.0, 0.3)
    twin = BackgroundMLP(frame_dim=8, frame_coupling=coupling).cuda()
    twin.load_state_dict(mlp.state_dict())
    graphed = ThermalBackground(mlp, WildThermalModelConfig(graphed_background=True))
    eager = ThermalBackground(twin, WildThermalModelConfig(graphed_background=False))
    embeddings = torch.nn.Parameter(torch.randn(3, 8, device="cuda"))
    pose = torch.eye(4, device="cuda")[:3]
    for step in range(6):
        width, height = (80, 64) if step % 2 else (160, 128)
        K = torch.tensor([[100.0, 0, width / 2], [0, 100.0, height / 2], [0, 0, 1]], device="cuda")
        weights = torch.rand(height, width, 1, device="cuda")
        results = []
        for background, net in ((graphed, mlp), (eager, twin)):
            embeddings.grad = None
            net.zero_grad(set_to_none=True)
            out = background.training(K, pose, embeddings[step % 3], width, height, cam_idx=step % 3)
            (out * weights).sum().backward()
            results.append((out.detach().clone(), embeddings.grad.clone(), _gradients(net)))
        (ours, ours_embed, ours_params), (reference, ref_embed, ref_params) = results
        assert torch.allclose(ours, reference, rtol=1e-6, atol=1e-7), step
        assert torch.allclose(ours_embed, ref_embed, rtol=1e-5, atol=1e-7), step
        for mine, theirs in zip(ours_params, ref_params):
            # a weight's gradient sums over every grid point of the frame, where cuBLAS may split the
            # sum otherwise under capture: its elements near zero differ relatively more than the
            # floats of one order, so the tolerance is relative to the largest element
            scale = theirs.abs().max().item()
            worst = (mine - theirs).abs().max().item()
            assert worst <= 1e-5 * scale, (step, tuple(mine.shape), worst, scale)
        with torch.no_grad():  # an optimizer step, in place, the same on both
            for mine, theirs in zip(mlp.parameters(), twin.parameters()):
                change = 0.01 * torch.randn_like(mine)
                mine.add_(change)
                theirs.add_(change)
    assert len(graphed.graphed.graphs) == 2 and all(g is not None for g in graphed.graphed.graphs.values())


def test_a_graphed_piece_records_in_a_fresh_process_and_feeds_its_parameters_gradients():
    """A module trained through `GraphedCalls` for a few steps in a fresh process: it is recorded (torch's
    capture did not fail, which a gradient node of its parameters made beforehand on the default stream
    made it do: c67b74c, every graph falling back to kernel by kernel) and its
    parameters get their gradients."""
    code = textwrap.dedent(
        """
        import torch
        from thermal_wild_ns.model.graphed import GraphedCalls
        torch.manual_seed(0)
        mlp = torch.nn.Sequential(torch.nn.Linear(8, 16), torch.nn.ReLU(), torch.nn.Linear(16, 1)).cuda()
        calls, x = GraphedCalls("test"), torch.rand(64, 8, device="cuda")
        for _ in range(3):
            mlp.zero_grad(set_to_none=True)
            calls(None, mlp, x).sum().backward()
        torch.cuda.synchronize()
        recorded = all(g is not None for g in calls.graphs.values())
        print("recorded", recorded, "grads", bool(mlp[0].weight.grad.abs().sum() > 0))
        """
    )
    root = Path(__file__).resolve().parents[1]
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root, timeout=300)
    assert "recorded True grads True" in result.stdout, result.stderr[-2000:]


def test_after_a_failed_capture_each_piece_runs_kernel_by_kernel_and_random_draws_still_work():
    """A capture that fails (here on a host read inside the recorded function, which no CUDA graph can hold)
    in each of the three recorders: the call gives the function's own result, the failure is remembered, and
    CUDA's random generator draws afterwards (a failed capture left it in capture mode: densification's
    `randn` then raised, 2026-12-05). A fresh process: a failure here must not reach the other tests."""
    code = textwrap.dedent(
        """
        import torch
        from thermal_wild_ns.model.graphed import GraphedCalls, PaddedRowCalls
        from thermal_wild_ns.rendering.captured import UNRECORDABLE, CapturedCalls

        class HostRead(torch.nn.Module):  # reads a value back to the host: a capture of it fails
            def __init__(self):
                super().__init__()
                self.linear = torch.nn.Linear(8, 1)
            def forward(self, x, *shared):
                out = self.linear(x)
                return out * float(out.sum().item() != 12345.0)

        torch.manual_seed(0)
        module, x = HostRead().cuda(), torch.rand(1500, 8, device="cuda", requires_grad=True)
        expected = module(x)
        checks = []
        graphed = GraphedCalls("test")
        checks.append(torch.equal(graphed(None, module, x), expected))
        checks.append(list(graphed.graphs.values()) == [None])
        torch.randn(3, device="cuda")
        padded = PaddedRowCalls("test")
        checks.append(torch.equal(padded(module, (x,), ()), expected))
        checks.append(len(padded.failed) == 1 and padded.recordings.get(0) is None)
        torch.randn(3, device="cuda")
        captured = CapturedCalls()
        with torch.no_grad():
            out = captured("key", lambda t: (module(t),), x)
        checks.append(torch.equal(out[0], expected))
        checks.append(captured.graphs["key"] is UNRECORDABLE)
        draws = torch.randn(1000, device="cuda")
        torch.cuda.synchronize()
        print("checks", checks, "draws", bool(draws.std() > 0.5))
        """
    )
    root = Path(__file__).resolve().parents[1]
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root, timeout=300)
    assert "checks [True, True, True, True, True, True] draws True" in result.stdout, (
        result.stdout[-2000:] + result.stderr[-3000:]
    )


def test_the_emission_mlp_replayed_as_cuda_graphs_equals_it_run_kernel_by_kernel():
    """The emission MLP through `PaddedRowCalls` (`graphed_emission`): the same emission and gradients
    (per-Gaussian scalars and embeddings, the frame embedding, the MLP's parameters) as kernel by kernel,
    up to the float rounding of cuBLAS's sums over padded rows, while the Gaussian count moves as
    densification moves it (grown and pruned within a capacity: one recording; past it and far under it: a
    new one, the latest alone kept), the parameters changed in place between steps, and each step's loss kept
    into the next as the trainer keeps it (its graph holds the parameters' gradient nodes, made on the step's
    stream: a recording that reached them failed its capture in training, 2026-12-05)."""
    from thermal_wild_ns.model.fields import EmissionMLP
    from thermal_wild_ns.model.graphed import PaddedRowCalls

    torch.manual_seed(0)
    mlp = EmissionMLP(16, 16).cuda()
    for parameter in mlp.parameters():  # the zero-initialised output layer would give zero gradients upstream
        parameter.data.normal_(0.0, 0.1)
    twin = EmissionMLP(16, 16).cuda()
    twin.load_state_dict(mlp.state_dict())
    graphed = PaddedRowCalls("emission MLP")
    frames = torch.nn.Parameter(torch.randn(3, 16, device="cuda"))
    capacities, kept = [], {}
    for step, count in enumerate((4000, 4000, 3500, 6000, 5000, 2000)):
        base = torch.nn.Parameter(torch.rand(count, 1, device="cuda"))
        embed = torch.nn.Parameter(0.1 * torch.randn(count, 16, device="cuda"))
        weights = torch.rand(count, 1, device="cuda")
        results = []
        for run, net in ((lambda *x: graphed(mlp, x[:2], x[2:]), mlp), (twin, twin)):
            for leaf in (base, embed, frames):
                leaf.grad = None
            net.zero_grad(set_to_none=True)
            out = run(base, embed, frames[step % 3])
            loss = (out * weights).sum()
            loss.backward()
            kept[id(net)] = loss  # as nerfstudio's trainer keeps the step's loss (and its graph) into the next step
            grads = [
                base.grad.clone(),
                embed.grad.clone(),
                frames.grad.clone(),
                *_gradients(net),
            ]
            results.append((out.detach().clone(), grads))
        (ours, ours_grads), (reference, reference_grads) = results
        assert ours.shape == reference.shape == (count, 1)
        assert torch.allclose(ours, reference, rtol=1e-5, atol=1e-6), (step, (ours - reference).abs().max())
        for mine, theirs in zip(ours_grads, reference_grads):
            # a weight's gradient sums over every Gaussian, which cuBLAS splits otherwise over padded rows:
            # the tolerance is relative to the largest element, as the background's
            worst = (mine - theirs).abs().max().item()
            assert worst <= 1e-5 * theirs.abs().max().item(), (step, tuple(mine.shape), worst)
        capacities.append(graphed.recordings[0].capacity)
        with torch.no_grad():  # an optimizer step, in place, the same on both
            for mine, theirs in zip(mlp.parameters(), twin.parameters()):
                change = 0.01 * torch.randn_like(mine)
                mine.add_(change)
                theirs.add_(change)
    assert capacities == [4096, 4096, 4096, 8192, 8192, 2048], capacities
    assert not graphed.failed and list(graphed.recordings) == [0]


def test_the_composite_and_camera_response_replayed_as_cuda_graphs_equal_them_run_kernel_by_kernel():
    """A training render's compositing over the background and the camera model's response through `GraphedCalls`
    (`graphed_camera`, `recorded_over_background`): the same image and the same gradients of the render, its
    alpha, the background, the fall-off's coefficients and the flat-field cells as kernel by kernel, for frames of
    two sizes in turn, with and without the map, the parameters changed in place between steps (as Adam does)."""
    from thermal_wild_ns.model.background import CameraFrameDirections
    from thermal_wild_ns.model.camera_falloff import FALLOFF_ORDER, falloff_basis
    from thermal_wild_ns.model.camera_response import recorded_over_background
    from thermal_wild_ns.model.graphed import GraphedCalls

    torch.manual_seed(0)
    graphed = GraphedCalls("camera model")
    coefficients = torch.nn.Parameter(0.1 * torch.randn(2, FALLOFF_ORDER, device="cuda"))
    cells = torch.nn.Parameter(0.1 * torch.randn(2, 8, 8, device="cuda"))
    bases = CameraFrameDirections(derive=falloff_basis)
    for step in range(8):
        width, height = (80, 64) if step % 2 else (160, 128)
        with_map = step < 4
        K = torch.tensor([[100.0, 0, width / 2], [0, 100.0, height / 2], [0, 0, 1]], device="cuda")
        basis = bases(K, (100.0, 100.0, width / 2, height / 2), width, height, 1)
        alpha = torch.rand(height, width, 1, device="cuda", requires_grad=True)
        emission = (alpha.detach() * torch.rand(height, width, 1, device="cuda")).requires_grad_()  # premultiplied
        background = torch.rand(height, width, 1, device="cuda", requires_grad=True)
        weights = torch.rand(height, width, 1, device="cuda")
        leaves = (emission, alpha, background, coefficients) + ((cells,) if with_map else ())
        inputs = leaves[:4] + (basis,) + leaves[4:]
        results = []
        for run in (functools.partial(graphed, with_map, recorded_over_background), recorded_over_background):
            for leaf in leaves:
                leaf.grad = None
            out = run(*inputs)
            (out * weights).sum().backward()
            results.append((out.detach().clone(), [leaf.grad.clone() for leaf in leaves]))
        (ours, ours_grads), (reference, reference_grads) = results
        assert torch.allclose(ours, reference, rtol=1e-6, atol=1e-7), step
        for mine, theirs, tolerance in zip(ours_grads, reference_grads, (1e-6, 1e-6, 1e-6, 1e-5, 1e-4)):
            # the parameters' gradients sum over every pixel: relative to the largest element; the map's
            # cells are summed by the bilinear upsampling's backward with atomic adds on the GPU, whose
            # order (hence the last bits of a float32 sum over hundreds of pixels) differs between any two
            # runs, graphed or not (docs/results/camera_graph_h200)
            worst = (mine - theirs).abs().max().item()
            assert worst <= tolerance * theirs.abs().max().item(), (step, tuple(mine.shape), worst)
        with torch.no_grad():  # an optimizer step, in place
            coefficients.add_(0.01 * torch.randn_like(coefficients))
            cells.add_(0.01 * torch.randn_like(cells))
    assert len(graphed.graphs) == 4 and all(g is not None for g in graphed.graphs.values())


def test_bilinear_resize_on_the_gpu_equals_torchs_interpolation_and_its_backward_repeats_exactly():
    """The flat-field cells' and the background grid's resize (`model/bilinear.py`): torch's values and
    gradients within float32 rounding (no TF32 in its products), and the same gradient bit for bit on
    every run (torch's bilinear backward adds with atomics, in no fixed order)."""
    import torch.nn.functional as F

    from thermal_wild_ns.model.bilinear import bilinear_resize

    generator = torch.Generator(device="cuda").manual_seed(0)
    for shape in ((2, 8, 8), (1, 128, 160)):
        grid = torch.randn(shape, device="cuda", generator=generator)
        weight = torch.randn(shape[0], 512, 640, device="cuda", generator=generator)
        theirs = grid.clone().requires_grad_(True)
        expected = F.interpolate(theirs[None], size=(512, 640), mode="bilinear", align_corners=False)[0]
        (expected * weight).sum().backward()
        grads = []
        for _ in range(2):
            ours = grid.clone().requires_grad_(True)
            resized = bilinear_resize(ours, 512, 640)
            (resized * weight).sum().backward()
            grads.append(ours.grad)
        torch.testing.assert_close(resized, expected, rtol=0, atol=1e-5)
        torch.testing.assert_close(grads[0], theirs.grad, rtol=1e-4, atol=1e-3 * float(theirs.grad.abs().max()))
        assert torch.equal(grads[0], grads[1])


def test_the_verdict_on_the_gpu_is_the_checks_it_stands_for_and_reads_back_its_own_step():
    """The guard's verdict on CUDA (its values reach the host through one pinned buffer, reused from step
    to step): the same checks as on the host, case by case, and a sequence of steps each reading back its
    own loss, not a later one's."""
    from test_guard import verdicts_match_the_reference

    from thermal_wild_ns.training.divergence import DivergenceGuard, DivergenceGuardConfig

    verdicts_match_the_reference("cuda")
    guard = DivergenceGuard(DivergenceGuardConfig(spike_window=100))
    param = torch.nn.Parameter(torch.ones(1000, device="cuda"))
    for step in range(20):
        param.grad = torch.full((1000,), float(step), device="cuda")
        guard.verdict(torch.tensor(float(step + 1), device="cuda"), {"g": [param]}, ["g"], frame=step, step=step)
    guard.settle()
    assert list(guard.recent) == [float(s + 1) for s in range(20)]
    assert guard.frame_loss == {s: float(s + 1) for s in range(20)}


def test_the_densification_statistics_replayed_as_a_cuda_graph_equal_them_run_kernel_by_kernel():
    """`BudgetedDefaultStrategy.graphed`: over steps of one camera and of two, a rejected step among them (the
    guard's verdict False: nothing added), at a size with screen radii and one without, and across a state
    replaced as a refinement replaces it, the recorded statistics equal the ones summed kernel by kernel, bit
    for bit; one recording per state and layout, the first step's share added once (not again by the
    recording's warm-up)."""
    from thermal_wild_ns.model.strategy import BudgetedDefaultStrategy

    g = torch.Generator(device="cuda").manual_seed(5)
    n = 3000
    params = {"means": torch.zeros(n, 3, device="cuda")}
    strategies = [BudgetedDefaultStrategy(graphed=graphed, refine_scale2d_stop_iter=100) for graphed in (True, False)]
    states = [s.initialize_state() for s in strategies]
    records = []
    for step, (cameras, width, accepted) in enumerate(
        [(1, 640, True), (1, 640, True), (1, 640, False), (2, 640, True), (1, 32, True), (1, 640, True)]
    ):
        if step == 5:  # a refinement's new state tensors
            for state in states:
                state.update({key: state[key] * 0.5 for key in ("grad2d", "count", "radii")})
        means2d = torch.zeros(cameras, n, 2, device="cuda")
        means2d.grad = torch.rand(cameras, n, 2, device="cuda", generator=g)
        radii = (torch.rand(cameras, n, device="cuda", generator=g) * 30).int()
        radii = radii * (torch.rand(cameras, n, device="cuda", generator=g) > 0.4)
        info = {"width": width, "height": width * 3 // 4, "n_cameras": cameras, "radii": radii, "means2d": means2d}
        info["accepted"] = torch.tensor(accepted, device="cuda")
        for strategy, state in zip(strategies, states):
            strategy._update_state(params, state, info)
        records.append(strategies[0]._statistics)
    for key in ("grad2d", "count", "radii"):
        assert torch.equal(states[0][key], states[1][key]), key
    assert records[0] is records[1] is records[2] and records[3] is not records[2] and records[5] is not records[4]
    assert not strategies[0]._statistics_failed
    assert states[1]["count"].max() == 3.5  # (1 + 1 + 2 + 1) accepted cameras, halved, then 1 more


def test_a_views_scores_on_the_gpu_are_its_scores_on_the_cpu():
    """The scorers compute PSNR and SSIM on their model's device (`evaluation.scores`): the same numbers as on a
    CPU, to float rounding, °C errors included."""
    import numpy as np

    from thermal_wild_ns.pipeline.evaluation import scores

    rng = np.random.default_rng(0)
    gt = rng.random((512, 640), dtype=np.float32)
    pred = np.clip(gt + 0.05 * rng.standard_normal((512, 640)).astype(np.float32), 0, 1)
    to_celsius = lambda x: 20.0 + 30.0 * np.asarray(x, dtype=np.float64)
    on_cpu, on_gpu = scores(pred, gt, to_celsius), scores(pred, gt, to_celsius, device="cuda")
    assert on_cpu.keys() == on_gpu.keys()
    assert all(on_gpu[k] == pytest.approx(on_cpu[k], rel=1e-5) for k in on_cpu), (on_cpu, on_gpu)
