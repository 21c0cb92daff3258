"""The compatibility layer: the version guard, and no reach into upstream internals elsewhere."""

import re
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
# what reaching into nerfstudio / gsplat / torchmetrics / torch internals looks like in this code base
UPSTREAM_INTERNALS = re.compile(
    r"def "
    r"(_grow_gs|_update_state|_setup|_load_images|_load_checkpoint)\b|train_unseen_cameras|optimizer_scaler_step_some"
    r"|LearnedPerceptualImagePatchSimilarity|add_safe_globals|_render_trajectory_video|\.write_ply\s*=|ns_export\.eval_setup\s*="
    r"|torch\.library\.Library|sys\.meta_path|Cameras\.__getitem__\s*="
)
SHIM = ROOT / "thermal_wild_ns/install/torchvision_shim.py"
"""The CPU torchvision trap's handling: apart from `_upstream` because it runs at interpreter start."""
PACKAGE_FACE = ROOT / "thermal_wild_ns/__init__.py"
"""Its import hook serves the package's own moved modules (`MOVED_MODULES`), not upstream's."""


def test_version_guard_names_what_is_wrong(monkeypatch):
    from importlib import metadata

    import thermal_wild_ns._upstream as upstream

    upstream.check_versions()  # the installed versions are the checked ones
    monkeypatch.setattr(metadata, "version", lambda name: {"nerfstudio": "1.1.4", "gsplat": "1.4.0"}[name])
    with pytest.raises(
        ImportError, match=r"needs nerfstudio==1\.1\.5, gsplat==1\.4\.0; found nerfstudio 1\.1\.4 \(needs 1\.1\.5\)"
    ):
        upstream.check_versions()
    monkeypatch.setenv(upstream.SKIP_VERSION_CHECK, "1")
    upstream.check_versions()  # the escape hatch


def test_no_upstream_internals_outside_the_compatibility_layer():
    offenders = []
    for path in sorted([*ROOT.glob("thermal_wild_ns/**/*.py"), *ROOT.glob("experiments/*.py")]):
        if "_upstream" in path.parts or path == SHIM or path == PACKAGE_FACE:
            continue
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if UPSTREAM_INTERNALS.search(line):
                offenders.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert not offenders, "\n".join(offenders)
    layer = "".join(path.read_text() for path in sorted((ROOT / "thermal_wild_ns/_upstream").glob("*.py")))
    for allowed, text in (("thermal_wild_ns/_upstream", layer), (SHIM, SHIM.read_text())):
        assert UPSTREAM_INTERNALS.search(text), allowed  # the pattern does find them there


def test_importing_the_package_patches_nothing():
    """A fresh interpreter imports every module of the plugin; torch's safe-load allow-list, the
    loaders of nerfstudio's exporter and renderer and torchmetrics' LPIPS stay upstream's."""
    import subprocess
    import sys

    code = (
        # upstream's own imports extend the allow-list (torch.distributed's DTensor types): import them first
        "import torch, pkgutil, importlib\n"
        "from nerfstudio.scripts import render, exporter, train, eval, viewer\n"
        "from nerfstudio.utils import writer\n"
        "import torchmetrics.image.lpip as lpip\n"
        "before = set(map(str, torch.serialization.get_safe_globals()))\n"
        "write_out_storage = writer.write_out_storage\n"
        "import thermal_wild_ns\n"
        "for m in pkgutil.walk_packages(thermal_wild_ns.__path__, 'thermal_wild_ns.'):\n"
        "    importlib.import_module(m.name)\n"
        "assert set(map(str, torch.serialization.get_safe_globals())) == before\n"
        "assert render._render_trajectory_video.__module__ == 'nerfstudio.scripts.render'\n"
        "assert exporter.eval_setup.__module__ == 'nerfstudio.utils.eval_utils'\n"
        "assert lpip.LearnedPerceptualImagePatchSimilarity.__module__ == 'torchmetrics.image.lpip'\n"
        "assert writer.write_out_storage is write_out_storage\n"
        "print('clean')\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert result.stdout.strip().endswith("clean"), result.stderr[-2000:]


def test_step_timings_are_written_with_the_losses_every_other_event_at_once(monkeypatch):
    """The per-step timings reach the event writers at the log steps alone; a loss put at any step,
    an image or a timing not of that list, are written at once; the terminal's table is untouched."""
    from thermal_wild_ns._upstream import lighter_event_writes  # before the writer: its import cycle

    from nerfstudio.utils import writer  # isort: skip

    written = []

    class Recorder(writer.Writer):
        def write_image(self, name, image, step):
            written.append((name, step))

        def write_scalar(self, name, scalar, step):
            written.append((name, step))

        def write_config(self, name, config_dict, step):
            pass

    monkeypatch.setattr(writer, "write_out_storage", writer.write_out_storage)  # put back after the test
    monkeypatch.setattr(writer, "EVENT_WRITERS", [Recorder()])
    monkeypatch.setattr(writer, "EVENT_STORAGE", [])  # not what an earlier run in this process left unwritten
    monkeypatch.setattr(writer, "GLOBAL_BUFFER", {"steps_per_log": 10, "events": {}, "max_buffer_size": 20})
    lighter_event_writes()
    lighter_event_writes()  # a second trainer in the process: installed once
    for step in range(25):
        writer.put_time(writer.EventName.TRAIN_RAYS_PER_SEC, 1.0, step)
        writer.put_scalar(writer.EventName.ETA, 1.0, step)
        writer.put_scalar("Train Iter (time)", 1.0, step)
        if step in (3, 10):
            writer.put_scalar("Train Loss", 0.5, step)
            writer.put_time(writer.EventName.TEST_RAYS_PER_SEC, 1.0, step, avg_over_steps=False)
        writer.write_out_storage()
    timings = {"Train Rays / Sec", "ETA (time)", "Train Iter (time)"}
    assert sorted({step for name, step in written if name in timings}) == [0, 10, 20]
    assert len([1 for name, _ in written if name in timings]) == 9
    assert [step for name, step in written if name == "Train Loss"] == [3, 10]
    assert [step for name, step in written if name == "Test Rays / Sec"] == [3, 10]
    assert writer.EVENT_STORAGE == []  # nothing left over for a later step
    # the running average behind the terminal's table took in every step
    assert len(writer.GLOBAL_BUFFER["events"]["Train Rays / Sec"]["buffer"]) == 20


def test_the_events_tensors_reach_the_writers_as_floats_read_back_together(monkeypatch):
    """The losses and metrics a step puts (device tensors, the loss requiring grad) reach every writer as
    the Python floats `float(tensor)` gives, without a read per value (`_local_scalar_dense`) and without
    torch's warning for reading a tensor that requires grad; the trainer's own loss dict keeps its
    tensors, and values that are not one-element tensors pass as they were."""
    import warnings

    from torch.utils._python_dispatch import TorchDispatchMode

    from thermal_wild_ns._upstream import lighter_event_writes  # before the writer: its import cycle

    from nerfstudio.utils import writer  # isort: skip

    written = {}

    class Recorder(writer.Writer):
        def write_image(self, name, image, step):
            written[name] = image

        def write_scalar(self, name, scalar, step):
            assert type(scalar) is float, (name, type(scalar))
            written[name] = scalar

        def write_config(self, name, config_dict, step):
            pass

    class Reads(TorchDispatchMode):
        def __init__(self):
            super().__init__()
            self.reads = 0

        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            self.reads += func is torch.ops.aten._local_scalar_dense.default
            return func(*args, **(kwargs or {}))

    monkeypatch.setattr(writer, "write_out_storage", writer.write_out_storage)  # put back after the test
    monkeypatch.setattr(writer, "EVENT_WRITERS", [Recorder(), Recorder()])
    monkeypatch.setattr(writer, "EVENT_STORAGE", [])
    monkeypatch.setattr(writer, "GLOBAL_BUFFER", {"steps_per_log": 10, "events": {}, "max_buffer_size": 20})
    lighter_event_writes()
    weight = torch.tensor(0.3, requires_grad=True)
    alpha = torch.tensor(1e-3, dtype=torch.float64)  # another dtype: read in a transfer of its own
    losses = {"l1": weight * 0.1, "ssim": weight * torch.tensor([0.7]), "alpha": alpha}
    metrics = {"psnr": torch.tensor(31.25), "gaussian_count": torch.tensor(12_497), "kept": 4, "name": "x"}
    expected = {f"Train Loss Dict/{k}": float(v.detach()) for k, v in losses.items()}
    expected.update({"Train Loss": float((weight * 2).detach()), "Train Metrics Dict/psnr": 31.25})
    expected.update({"Train Metrics Dict/gaussian_count": 12497.0, "Train Metrics Dict/kept": 4.0})
    writer.put_scalar("Train Loss", weight * 2, 10)
    writer.put_dict("Train Loss Dict", losses, 10)
    writer.put_dict("Train Metrics Dict", {k: v for k, v in metrics.items() if k != "name"}, 10)
    writer.put_scalar("GPU Memory (MB)", 812.5, 10)
    expected["GPU Memory (MB)"] = 812.5
    with warnings.catch_warnings(record=True) as caught, Reads() as reads:
        warnings.simplefilter("always")
        writer.write_out_storage()
    assert written == expected
    assert reads.reads == 0
    assert not [w for w in caught if "requires_grad" in str(w.message)], [str(w.message) for w in caught]
    assert all(isinstance(v, torch.Tensor) for v in losses.values())  # the trainer's dict as it was
    assert writer.EVENT_STORAGE == []


@pytest.mark.parametrize(
    "device",
    ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA"))],
)
def test_fused_adam_step_is_adams_step(device):
    """`fused_adam_step` over several optimizers (with and without weight decay, two of the same settings,
    which share one fused call, parameters without gradients, a state created mid-way as densification
    creates one) against each optimizer's own
    `step()`, bit for bit over a few steps; a step the divergence guard rejects on the device
    (`accepted` False) is one torch never took, an accepted one is `step()`. On the CPU and, where
    there is one, a GPU (the training step's device: its fused kernel is another)."""
    from thermal_wild_ns._upstream import fused_adam_ready, fused_adam_step

    def build():
        torch.manual_seed(0)
        params = [torch.nn.Parameter(torch.randn(n, 3, device=device)) for n in (5, 7, 4, 2)]
        return params, [
            torch.optim.Adam([params[0]], lr=1e-2, eps=1e-15, fused=True),
            torch.optim.Adam([params[1]], lr=3e-3, weight_decay=1e-2, fused=True),
            torch.optim.Adam([params[2]], lr=1e-2, eps=1e-15, fused=True),  # the first one's settings
            torch.optim.AdamW([params[3]], lr=1e-3, weight_decay=1e-1, fused=True),
        ]

    mine, theirs = build(), build()
    assert all(fused_adam_ready(o) for o in mine[1][:3]) and not fused_adam_ready(mine[1][3])  # AdamW: no
    assert not fused_adam_ready(torch.optim.Adam([torch.nn.Parameter(torch.ones(1))]))  # not fused
    verdicts = [None, torch.tensor(True), torch.tensor(False), None, torch.tensor(True)]  # step 2 rejected
    verdicts = [v if v is None else v.to(device) for v in verdicts]
    for step, accepted in enumerate(verdicts):
        for (params, optimizers), stepper in ((mine, "ours"), (theirs, "torch")):
            torch.manual_seed(step)
            for k, p in enumerate(params):
                p.grad = None if (step == 0 and k == 1) else torch.randn_like(p)  # the second starts at step 1
            if stepper == "ours":
                fused_adam_step(optimizers[:3], accepted)
                if accepted is None or bool(accepted):
                    optimizers[3].step()
            elif accepted is None or bool(accepted):
                for optimizer in optimizers:
                    optimizer.step()
    assert float(mine[1][0].state[mine[0][0]]["step"]) == 4  # five steps, one rejected
    for p, q, o, r in zip(mine[0], theirs[0], mine[1], theirs[1]):
        assert torch.equal(p, q)
        assert o.state[p].keys() == r.state[q].keys()
        assert all(torch.equal(o.state[p][key], r.state[q][key]) for key in o.state[p])


def test_a_camera_paths_unit_slices_are_nerfstudios_without_the_rebuild():
    """`camera_unit_slice` (and `fast_camera_path_slices`, as ns-render's loop slices): for every frame of a path's
    batch, the same fields as nerfstudio's `cameras[i : i + 1]`: values, shapes, dtypes, and views of the same
    storage at the same offset (what `camera_views.CameraSizes` reads by); batches it does not handle go
    nerfstudio's way; the patch is gone after the context."""
    import dataclasses

    from nerfstudio.cameras.cameras import Cameras
    from nerfstudio.utils.tensor_dataclass import TensorDataclass

    from thermal_wild_ns._upstream import camera_unit_slice, fast_camera_path_slices

    n = 5
    g = torch.Generator().manual_seed(0)
    path = Cameras(
        camera_to_worlds=torch.rand(n, 3, 4, generator=g),
        fx=torch.rand(n, 1, generator=g) * 500,
        fy=torch.rand(n, 1, generator=g) * 500,
        cx=torch.full((n, 1), 320.0),
        cy=torch.full((n, 1), 256.0),
        width=torch.full((n, 1), 640),
        height=torch.full((n, 1), 512),
        distortion_params=torch.rand(n, 6, generator=g),
        times=torch.linspace(0, 1, n)[:, None],
        metadata={"label": "path"},
    )

    def same(ours, theirs):
        assert type(ours) is type(theirs) and ours.shape == theirs.shape
        assert ours.metadata == theirs.metadata and ours.metadata is not path.metadata
        for field in dataclasses.fields(theirs):
            a, b = getattr(ours, field.name), getattr(theirs, field.name)
            if isinstance(b, torch.Tensor):
                assert a.shape == b.shape and a.dtype == b.dtype and torch.equal(a, b), field.name
                assert a.untyped_storage().data_ptr() == b.untyped_storage().data_ptr(), field.name
                assert a.storage_offset() == b.storage_offset(), field.name
            else:
                assert a == b, field.name

    for i in range(n):
        same(camera_unit_slice(path, i), path[i : i + 1])
    with fast_camera_path_slices():
        assert path[2:3].camera_to_worlds.storage_offset() == 2 * 12
        same(path[3:4], TensorDataclass.__getitem__(path, slice(3, 4)))
        assert path[1:3].shape == (2,)  # not a unit slice: nerfstudio's
        tensors_inside = Cameras(
            **{
                **{f.name: getattr(path, f.name) for f in dataclasses.fields(path)},
                "metadata": {"cam_idx": torch.arange(n)[:, None]},
            }
        )
        assert tensors_inside[4:5].metadata["cam_idx"].tolist() == [[4]]  # nerfstudio's way
    assert "__getitem__" not in Cameras.__dict__


def test_the_startup_file_loads_the_shim_alone():
    """The `.pth` line the CPU install ships runs at interpreter start: it must find the shim in the
    installed package, install its import hook, and import neither the package nor torch."""
    import subprocess
    import sys

    line = (ROOT / "thermal_wild_ns/install/thermal_wild_ns_torchvision_cpu.pth").read_text().strip()
    code = (
        f"import sys\nsitedir = {str(ROOT)!r}\n{line}\n"
        "print(any(type(f).__name__ == 'TorchvisionFinder' for f in sys.meta_path),"
        " 'torch' in sys.modules, 'thermal_wild_ns' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-S", "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["True", "False", "False"]


def test_a_config_naming_a_moved_module_still_loads():
    """config.yml of a run trained before a module moved (`MOVED_MODULES`) names the old module path;
    nerfstudio's loader (yaml) must still build each class it names there."""
    import yaml

    import thermal_wild_ns
    from thermal_wild_ns.pipeline.datamanager import ThermalDatamanagerConfig
    from thermal_wild_ns.training.divergence import DivergenceGuardConfig

    named = {  # a class each old module held, as a run's config names it, and a field to read back
        "thermal_wild_ns.data.datamanager": (ThermalDatamanagerConfig, "camera_res_scale_factor", 0.5),
        "thermal_wild_ns.training.guard": (DivergenceGuardConfig, "max_rollbacks", 7),
    }
    assert set(named) == set(thermal_wild_ns.MOVED_MODULES)
    for old, (cls, field, value) in named.items():
        config = yaml.load(f"!!python/object:{old}.{cls.__name__} {{{field}: {value}}}", Loader=yaml.Loader)
        assert type(config) is cls and getattr(config, field) == value


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_fused_adam_step_does_not_wait_for_the_gpu():
    """The training step's optimizers take the divergence guard's verdict on the device: stepping them
    must not read it back (a host sync at every step leaves the GPU idle while the host catches up).
    torch raises in its sync debug mode "error" where a call waits for the GPU."""
    from thermal_wild_ns._upstream import fused_adam_step

    params = [torch.nn.Parameter(torch.randn(n, 3, device="cuda")) for n in (5, 7)]
    optimizers = [torch.optim.Adam([p], lr=1e-2, fused=True) for p in params]
    for step in range(3):
        for p in params:
            p.grad = torch.randn_like(p)
        accepted = torch.tensor(step != 1, device="cuda")
        torch.cuda.synchronize()
        torch.cuda.set_sync_debug_mode("error")
        try:
            fused_adam_step(optimizers, accepted)
        finally:
            torch.cuda.set_sync_debug_mode("default")
    assert float(optimizers[0].state[params[0]]["step"]) == 2  # three steps, one rejected


def test_a_refinement_keeps_the_allocators_cache(monkeypatch):
    """gsplat 1.4.0 empties torch's CUDA cache after every refinement; the plugin's strategy grows and
    prunes as gsplat's does without that call, and leaves `torch.cuda.empty_cache` as it was, also
    when the refinement fails."""
    from thermal_wild_ns.model.strategy import BudgetedDefaultStrategy

    calls = []
    monkeypatch.setattr(torch.cuda, "empty_cache", lambda: calls.append(1))
    original = torch.cuda.empty_cache
    strategy = BudgetedDefaultStrategy(refine_start_iter=0, refine_every=10, reset_every=10_000, verbose=False)
    n = 50
    g = torch.Generator().manual_seed(0)
    params = torch.nn.ParameterDict(
        {
            "means": torch.randn(n, 3, generator=g),
            "scales": torch.full((n, 3), -2.0),
            "quats": torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1),
            "opacities": torch.full((n,), 0.5),
        }
    )
    optimizers = {k: torch.optim.Adam([p], lr=1e-3) for k, p in params.items()}
    state = strategy.initialize_state()
    means2d = torch.zeros(1, n, 2)
    means2d.grad = torch.full((1, n, 2), 1.0)  # every Gaussian far above the growth threshold
    info = {"width": 64, "height": 48, "n_cameras": 1, "radii": torch.full((1, n), 3), "means2d": means2d}
    strategy.step_post_backward(params, optimizers, state, 10, info)
    assert params["means"].shape[0] > n  # it grew
    assert not calls and torch.cuda.empty_cache is original
    with pytest.raises(KeyError):
        strategy.step_post_backward(params, optimizers, state, 20, {k: v for k, v in info.items() if k != "radii"})
    assert torch.cuda.empty_cache is original
    torch.cuda.empty_cache()
    assert calls == [1]  # the function itself still works


def test_adam_groups_of_the_same_settings_share_one_fused_call(monkeypatch):
    """One `torch._fused_adam_` call per distinct (learning rate, betas, weight decay, eps), in the groups' order:
    host work per call, the same numbers either way (`test_fused_adam_step_is_adams_step`)."""
    from thermal_wild_ns._upstream import fused_adam_step

    calls = []
    fused = torch._fused_adam_
    monkeypatch.setattr(
        torch, "_fused_adam_", lambda params, *a, **k: calls.append((len(params), k["lr"])) or fused(params, *a, **k)
    )
    params = [torch.nn.Parameter(torch.ones(3)) for _ in range(4)]
    for p in params:
        p.grad = torch.ones(3)
    optimizers = [
        torch.optim.Adam([params[0]], lr=1e-3, fused=True),
        torch.optim.Adam([params[1]], lr=1e-2, fused=True),
        torch.optim.Adam([params[2]], lr=1e-3, fused=True),
        torch.optim.Adam([params[3]], lr=1e-3, weight_decay=1e-6, fused=True),
    ]
    fused_adam_step(optimizers)
    assert calls == [(2, 1e-3), (1, 1e-2), (1, 1e-3)]


def test_a_profiled_section_costs_nothing_without_a_profiler_and_is_named_with_one():
    """`profiled_section` dispatches no operation while no profiler records (torch's `record_function` does,
    at every section of every step), and is the named range in a torch profiler's events while one does."""
    from torch.profiler import ProfilerActivity, profile, record_function
    from torch.utils._python_dispatch import TorchDispatchMode

    from thermal_wild_ns._upstream import profiled_section

    class Count(TorchDispatchMode):
        ops = 0

        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            Count.ops += 1
            return func(*args, **(kwargs or {}))

    for section, dispatches in ((record_function, True), (profiled_section, False)):
        Count.ops = 0
        with Count():
            with section("thermal/test"):
                pass
        assert (Count.ops > 0) == dispatches, section
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        with profiled_section("thermal/test"):
            torch.ones(4).sum()
    assert "thermal/test" in {event.key for event in prof.key_averages()}


def test_export_commands_import_without_the_mesh_libraries():
    """The light install has none of open3d, xatlas, pymeshlab and scikit-image, which nerfstudio's exporter modules
    import at their tops: the plugin's export commands (Gaussian splat, °C points, orthomosaic) must load anyway, a
    point-cloud or mesh export say what is missing, and the libraries stay absent for everyone else."""
    import subprocess
    import sys

    from thermal_wild_ns._upstream.commands import MESH_EXPORT_LIBRARIES

    blocking = "import sys\n" + "".join(f"sys.modules[{name!r}] = None\n" for name in MESH_EXPORT_LIBRARIES)
    for name in MESH_EXPORT_LIBRARIES:  # nerfstudio's own import fails without each of them
        alone = f"import sys\nsys.modules[{name!r}] = None\nfrom nerfstudio.scripts import exporter\n"
        blocked = subprocess.run([sys.executable, "-c", alone], capture_output=True, text=True)
        assert blocked.returncode != 0 and f"import of {name} halted" in blocked.stderr, (name, blocked.stderr[-300:])

    script = (
        blocking
        + """
from thermal_wild_ns.export.commands import ExportThermalSplat
from thermal_wild_ns._upstream import nerfstudio_exporter
from nerfstudio.exporter import tsdf_utils
exporter = nerfstudio_exporter()
assert issubclass(ExportThermalSplat, exporter.ExportGaussianSplat)
for call, pip_name in ((lambda: exporter.o3d.io.write_point_cloud("x.ply", None), "open3d"),
                       (lambda: tsdf_utils.measure.marching_cubes(None), "scikit-image"),
                       (lambda: tsdf_utils.pymeshlab.MeshSet(), "pymeshlab")):
    try:
        call()
    except ImportError as error:
        assert f"pip install {pip_name}" in str(error), error
    else:
        raise AssertionError("the stand-in ran a call")
assert all(sys.modules[name] is None for name in %r)  # others still see none of them
print("ok")
"""
        % (list(MESH_EXPORT_LIBRARIES),)
    )
    loaded = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert loaded.returncode == 0 and loaded.stdout.strip() == "ok", loaded.stderr[-2000:]
