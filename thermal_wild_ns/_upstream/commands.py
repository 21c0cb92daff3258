"""nerfstudio's commands (ns-render, ns-export, ns-eval, ns-viewer): what they load, check and call (the
package's docstring says how each patch is kept)."""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import importlib
import os
import shutil
import sys
import types
from pathlib import Path
from typing import Callable, Optional

import torch
import torchmetrics.image.lpip as lpip
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.utils.tensor_dataclass import TensorDataclass
from nerfstudio.viewer.viewer_elements import ViewerControl

from thermal_wild_ns._upstream.torch_internals import allow_nerfstudio_checkpoints
from thermal_wild_ns.errors import EXPLAINERS, raised_reading_yaml


def provide_ffmpeg() -> None:
    """nerfstudio 1.1.5's ns-render refuses to start without an `ffmpeg` on PATH and writes every
    output through it. Where the system has none, put the static ffmpeg of the imageio-ffmpeg
    wheel on this process's PATH (a link named `ffmpeg` in ~/.cache/thermal_wild_ns/bin, made
    atomically so concurrent processes never see half of it). Applied with the checkpoint
    allow-list, when a pipeline of this plugin is built."""
    if shutil.which("ffmpeg") is not None:
        return
    try:
        import imageio_ffmpeg  # optional: where it is missing, nerfstudio says ffmpeg is

        executable = Path(imageio_ffmpeg.get_ffmpeg_exe())
        folder = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "thermal_wild_ns" / "bin"
        folder.mkdir(parents=True, exist_ok=True)
        link = folder / "ffmpeg"
        if not link.exists() or link.resolve() != executable.resolve():
            tmp = folder / f".ffmpeg-{os.getpid()}"
            tmp.unlink(missing_ok=True)
            tmp.symlink_to(executable)
            tmp.replace(link)
    except (ImportError, OSError, RuntimeError):
        return  # no bundled ffmpeg or no writable cache: nerfstudio says what is missing
    os.environ["PATH"] = f"{folder}{os.pathsep}{os.environ.get('PATH', '')}"


def prepare_checkpoint_commands() -> None:
    """What nerfstudio's loading commands need from this plugin (see the two functions called)."""
    allow_nerfstudio_checkpoints()
    provide_ffmpeg()


@contextlib.contextmanager
def no_lpips_download():
    """Stock splatfacto (nerfstudio 1.1.5) builds torchmetrics' LPIPS in `populate_modules`, and its
    constructor downloads AlexNet weights: offline, the model cannot be built. While this context
    is open, the class is a stub that returns NaN (the experiments never read LPIPS). Checked with
    torchmetrics 1.4-1.9."""

    class NoLPIPS(torch.nn.Module):
        def __init__(self, *args, **kwargs):
            super().__init__()

        def forward(self, *args, **kwargs):
            return torch.tensor(float("nan"))

    original = lpip.LearnedPerceptualImagePatchSimilarity
    lpip.LearnedPerceptualImagePatchSimilarity = NoLPIPS
    try:
        yield
    finally:
        lpip.LearnedPerceptualImagePatchSimilarity = original


class ViewerControlOnConnect(ViewerControl):
    """nerfstudio 1.1.5's `ViewerControl` is handed the viewer through its private `_setup` when
    the viewer starts; it has no public hook for a browser connecting. This subclass calls
    `on_connect(client)` for every browser that connects (to open the view through a camera)."""

    def __init__(self, on_connect):
        self.on_connect = on_connect

    def _setup(self, viewer) -> None:
        super()._setup(viewer)
        viewer.viser_server.on_client_connect(self.on_connect)

    def started_viewer(self):
        """The viewer this control was handed (`_setup`), or None before a viewer started."""
        return getattr(self, "viewer", None)


def explain_config_load_error(error: BaseException, traceback) -> Optional[str]:
    """nerfstudio 1.1.5's `eval_setup` (ns-eval, ns-render, ns-viewer, ns-export) reads a run's config
    with `yaml.load(config_path.read_text())`: a damaged file fails there with a YAML error about
    "<unicode string>", (cut short at a line end) with the plugin's `IncompleteConfig`, or (cut
    inside a tag) with whatever the object it then names raises (`errors.raised_reading_yaml`), none
    naming the file. Where `error` rose inside `eval_setup`, the one-line explanation naming its
    `config_path` (a local of that function); None for any other error. One of `errors.EXPLAINERS`."""
    if not raised_reading_yaml(error, traceback):
        return None
    while traceback is not None:
        frame = traceback.tb_frame
        if frame.f_code.co_name == "eval_setup" and "config_path" in frame.f_locals:
            problem = " ".join(str(error).split())
            return (
                f"{frame.f_locals['config_path']}: the run's config is damaged or cut short ({problem}); "
                "restore it from a copy, or train the run again"
            )
        traceback = traceback.tb_next
    return None


MESH_EXPORT_LIBRARIES = {"open3d": "open3d", "xatlas": "xatlas", "pymeshlab": "pymeshlab", "skimage": "scikit-image"}
"""The libraries nerfstudio 1.1.5's exporter modules import at their tops for the point-cloud and mesh exports alone
(module name: pip name); the light install has none of them."""


class _MissingLibrary(types.ModuleType):
    """Stands in, in nerfstudio's exporter modules only, for a library of their point-cloud and mesh exports that is
    not installed: importing it and looking up its names pass (`from skimage import measure` at a module's top),
    calling anything of it says what is missing."""

    def __getattr__(self, name: str):
        if name.startswith("__"):  # what `inspect` and `hasattr` probe on every module
            raise AttributeError(name)
        return _MissingLibrary(f"{self.__name__}.{name}")

    def __call__(self, *args, **kwargs):
        library = self.__name__.split(".")[0]
        raise ImportError(
            f"{self.__name__}: {library} is not installed (the light install leaves it out); nerfstudio's point-cloud "
            f"and mesh exports need it: pip install {MESH_EXPORT_LIBRARIES[library]}"
        )


def _imports(name: str) -> bool:
    try:
        importlib.import_module(name)
    except (ImportError, OSError):  # OSError: open3d present but its system library (libusb) missing
        return False
    return True


def nerfstudio_exporter() -> types.ModuleType:
    """nerfstudio 1.1.5's `nerfstudio.scripts.exporter`, importable without its mesh libraries.

    The module (and the `nerfstudio.exporter` modules it imports) import open3d, xatlas, pymeshlab and scikit-image
    at their tops for the point-cloud and mesh exports; the Gaussian-splat export (the only one this plugin extends)
    uses none, and the light install has none. Each that does not import gets a stand-in while nerfstudio's modules
    load (`_MissingLibrary`: a call of it raises), and stays absent for everyone else."""
    name = "nerfstudio.scripts.exporter"
    if name in sys.modules:
        return sys.modules[name]
    missing = [library for library in MESH_EXPORT_LIBRARIES if not _imports(library)]
    before = {library: sys.modules.get(library, _MissingLibrary) for library in missing}
    sys.modules.update({library: _MissingLibrary(library) for library in missing})
    try:
        return importlib.import_module(name)
    finally:
        for library, module in before.items():
            if module is _MissingLibrary:
                del sys.modules[library]
            else:
                sys.modules[library] = module


@contextlib.contextmanager
def gaussian_splat_export_hooks(
    on_pipeline: Callable, extra_properties: Callable[[dict], None], header_comments: Callable[[], list]
):
    """nerfstudio 1.1.5's `ExportGaussianSplat.main` loads the pipeline through the module-level
    `eval_setup` and writes the PLY through the static `write_ply(filename, count, map_to_tensors)`,
    neither of which can be extended. While this context is open: `on_pipeline(pipeline)` sees the
    loaded pipeline; `extra_properties(map_to_tensors)` may add vertex properties before writing;
    `header_comments()` lines are inserted after nerfstudio's "comment Vertical Axis: z" header
    line. The PLY is written under a temporary name and renamed into place."""
    ns_export = nerfstudio_exporter()

    original_setup, original_write = ns_export.eval_setup, ns_export.ExportGaussianSplat.write_ply

    def eval_setup(*args, **kwargs):
        result = original_setup(*args, **kwargs)
        on_pipeline(result[1])
        return result

    def write_ply(filename, count, map_to_tensors):
        extra_properties(map_to_tensors)
        partial = Path(filename).with_suffix(".partial.ply")
        original_write(str(partial), count, map_to_tensors)
        data = partial.read_bytes()
        anchor = b"comment Vertical Axis: z\n"
        if anchor not in data:
            raise RuntimeError(f"{partial}: nerfstudio's PLY header changed (no '{anchor.decode().strip()}' line)")
        comments = "".join(f"comment {line}\n" for line in header_comments()).encode()
        partial.write_bytes(data.replace(anchor, anchor + comments, 1))
        partial.replace(filename)  # never a half-written PLY under the final name

    with contextlib.ExitStack() as stack:
        ns_export.eval_setup = eval_setup
        stack.callback(setattr, ns_export, "eval_setup", original_setup)
        ns_export.ExportGaussianSplat.write_ply = staticmethod(write_ply)
        stack.callback(setattr, ns_export.ExportGaussianSplat, "write_ply", staticmethod(original_write))
        yield


@contextlib.contextmanager
def interpolation_over_one_pose():
    """nerfstudio 1.1.5's `ns-render interpolate` crashes inside numpy ("need at least one array to
    stack") where its pose source holds one camera (a small capture's one held-out view): there is
    no pair to interpolate between. While this context is open, such a path is that one pose, so
    the command renders it."""
    from nerfstudio.scripts import render as ns_render  # a command script: see the module docstring

    original = ns_render.get_interpolated_camera_path

    def interpolated(cameras, steps, order_poses):
        if len(cameras) > 1:
            return original(cameras, steps, order_poses)
        Ks = cameras.get_intrinsics_matrices()  # [1, 3, 3]
        return Cameras(
            fx=Ks[:, 0, 0],
            fy=Ks[:, 1, 1],
            cx=Ks[0, 0, 2],
            cy=Ks[0, 1, 2],
            camera_type=cameras.camera_type[0],
            camera_to_worlds=cameras.camera_to_worlds,
        )

    ns_render.get_interpolated_camera_path = interpolated
    try:
        yield
    finally:
        ns_render.get_interpolated_camera_path = original


@contextlib.contextmanager
def trajectory_render_hooks(per_trajectory: Callable):
    """nerfstudio 1.1.5's ns-render commands render a camera path in the module-level
    `_render_trajectory_video(pipeline, ...)`, calling `pipeline.model.get_outputs_for_camera` per
    frame, with no hook. While this context is open, each such call runs inside the context
    manager `per_trajectory(pipeline)`, which yields `(frame_embedding, on_outputs)`: every frame is
    rendered with `frame_embedding=` that embedding (where not None), and `on_outputs`, if not None,
    is called with every frame's outputs (the same renders as the video, not a second pass)."""
    from nerfstudio.scripts import render as ns_render  # a command script: see the module docstring

    original = ns_render._render_trajectory_video

    def trajectory(pipeline, *args, **kwargs):
        model = pipeline.model
        with per_trajectory(pipeline) as (frame_embedding, on_outputs):
            if frame_embedding is None and on_outputs is None:
                return original(pipeline, *args, **kwargs)
            render = model.get_outputs_for_camera
            at_state = {} if frame_embedding is None else {"frame_embedding": frame_embedding}

            def recording(*render_args, **render_kwargs):
                outputs = render(*render_args, **render_kwargs, **at_state)
                if on_outputs is not None:
                    on_outputs(outputs)
                return outputs

            model.get_outputs_for_camera = recording
            try:
                return original(pipeline, *args, **kwargs)
            finally:
                del model.get_outputs_for_camera  # back to the class's method

    ns_render._render_trajectory_video = trajectory
    try:
        yield
    finally:
        ns_render._render_trajectory_video = original


def camera_unit_slice(cameras: Cameras, i: int) -> Cameras:
    """`cameras[i : i + 1]` of a 1-D batch without nerfstudio 1.1.5's `TensorDataclass.__getitem__`, which builds
    the slice through `Cameras.__init__` (its field conversions, checks and broadcasts: host time in every frame of
    a camera path) to the same tensors: each tensor field is the view `field[i : i + 1]` (the same storage, offset
    and values), metadata without tensors deep-copied as there. Other batches and metadata holding tensors take
    nerfstudio's way (`tests/test_upstream.py` compares the two field by field)."""
    metadata = cameras.metadata
    sliced_inside = (torch.Tensor, dict, TensorDataclass)  # metadata values nerfstudio slices, not copies
    simple = metadata is None or not any(isinstance(v, sliced_inside) for v in metadata.values())
    if len(cameras.shape) != 1 or not 0 <= i < cameras.shape[0] or not simple:
        return TensorDataclass.__getitem__(cameras, slice(i, i + 1))
    sliced = copy.copy(cameras)
    for field in dataclasses.fields(cameras):
        value = getattr(cameras, field.name)
        if isinstance(value, torch.Tensor):
            object.__setattr__(sliced, field.name, value[i : i + 1])
    object.__setattr__(sliced, "metadata", copy.deepcopy(metadata))
    object.__setattr__(sliced, "_shape", torch.Size([1]))
    return sliced


@contextlib.contextmanager
def fast_camera_path_slices():
    """nerfstudio 1.1.5's ns-render loop (`_render_trajectory_video`) hands the model `cameras[i : i + 1]` of the
    path's batch for every frame. While this context is open, that unit slice of a `Cameras` batch is
    `camera_unit_slice`'s: the same camera, without the dataclass rebuilt per frame."""

    def getitem(self, indices):
        if isinstance(indices, slice) and indices.step is None and isinstance(indices.start, int):
            if indices.stop == indices.start + 1:
                return camera_unit_slice(self, indices.start)
        return TensorDataclass.__getitem__(self, indices)

    previous = Cameras.__dict__.get("__getitem__")  # none: Cameras inherits TensorDataclass's
    Cameras.__getitem__ = getitem
    try:
        yield
    finally:
        if previous is None:
            del Cameras.__getitem__
        else:
            Cameras.__getitem__ = previous


EXPLAINERS.append(explain_config_load_error)  # a damaged run config, as nerfstudio's loader meets it
