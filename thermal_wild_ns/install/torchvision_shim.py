"""The CPU install's torchvision trap: PyPI's torchvision wheel is a CUDA build, and on a CPU-only torch
`import torchvision` dies before nerfstudio can use its image utilities.

The CPU install's `.pth` file (`thermal_wild_ns_torchvision_cpu.pth`, shipped by `build_hooks.py`) loads
this file on its own at interpreter start and calls `install_torchvision_cpu_shim`: it has to act before
anything imports torchvision, so this module imports only the standard library at its top (torch inside
the function that runs when torchvision is first imported) and nothing of the package.
"""

from __future__ import annotations

import glob
import importlib.abc
import importlib.machinery
import os
import sys

_TORCHVISION_SCHEMAS = (
    "nms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor",
    "qnms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor",
    "roi_align(Tensor input, Tensor rois, float spatial_scale, SymInt pooled_height, SymInt pooled_width, "
    "int sampling_ratio, bool aligned) -> Tensor",
    "qroi_align(Tensor input, Tensor rois, float spatial_scale, SymInt pooled_height, SymInt pooled_width, "
    "int sampling_ratio, bool aligned) -> Tensor",
    "_roi_align_backward(Tensor grad, Tensor rois, float spatial_scale, SymInt pooled_height, "
    "SymInt pooled_width, SymInt batch_size, SymInt channels, SymInt height, SymInt width, int sampling_ratio, "
    "bool aligned) -> Tensor",
    "ps_roi_align(Tensor input, Tensor rois, float spatial_scale, SymInt pooled_height, SymInt pooled_width, "
    "int sampling_ratio) -> (Tensor, Tensor)",
    "_ps_roi_align_backward(Tensor grad, Tensor rois, Tensor channel_mapping, float spatial_scale, "
    "SymInt pooled_height, SymInt pooled_width, int sampling_ratio, SymInt batch_size, SymInt channels, "
    "SymInt height, SymInt width) -> Tensor",
    "roi_pool(Tensor input, Tensor rois, float spatial_scale, SymInt pooled_height, SymInt pooled_width) "
    "-> (Tensor, Tensor)",
    "_roi_pool_backward(Tensor grad, Tensor rois, Tensor argmax, float spatial_scale, SymInt pooled_height, "
    "SymInt pooled_width, SymInt batch_size, SymInt channels, SymInt height, SymInt width) -> Tensor",
    "ps_roi_pool(Tensor input, Tensor rois, float spatial_scale, SymInt pooled_height, SymInt pooled_width) "
    "-> (Tensor, Tensor)",
    "_ps_roi_pool_backward(Tensor grad, Tensor rois, Tensor channel_mapping, float spatial_scale, "
    "SymInt pooled_height, SymInt pooled_width, SymInt batch_size, SymInt channels, SymInt height, "
    "SymInt width) -> Tensor",
    "deform_conv2d(Tensor input, Tensor weight, Tensor offset, Tensor mask, Tensor bias, SymInt stride_h, "
    "SymInt stride_w, SymInt pad_h, SymInt pad_w, SymInt dilation_h, SymInt dilation_w, SymInt groups, "
    "SymInt offset_groups, bool use_mask) -> Tensor",
    "_deform_conv2d_backward(Tensor grad, Tensor input, Tensor weight, Tensor offset, Tensor mask, "
    "Tensor bias, SymInt stride_h, SymInt stride_w, SymInt pad_h, SymInt pad_w, SymInt dilation_h, "
    "SymInt dilation_w, SymInt groups, SymInt offset_groups, bool use_mask) -> "
    "(Tensor, Tensor, Tensor, Tensor, Tensor)",
)
"""torchvision's op schemas as its C++ registers them (torchvision/csrc/ops/*.cpp, 0.2x)."""
_torchvision_library = None  # keeps the torch.library.Library alive


def define_torchvision_ops(package_dir: str) -> bool:
    """PyPI's torchvision wheel is a CUDA build: on a CPU-only torch its `_C` extension fails to
    load, and `import torchvision` then dies in `_meta_registrations` ("operator torchvision::nms
    does not exist"). nerfstudio imports torchvision for image utilities, never its CUDA ops. Where
    `_C` cannot load, define the schemas of the operators torchvision registers meta kernels for:
    they exist but have no kernel (torchvision.ops.nms raises NotImplementedError); the rest of
    torchvision works. Returns True if it defined them. Checked with torchvision 0.24-0.29."""
    global _torchvision_library
    import torch  # not at the top: this file loads at interpreter start, before torch is wanted

    for lib in glob.glob(os.path.join(package_dir, "_C*.so")):
        try:
            torch.ops.load_library(lib)
            return False  # a working extension defines the ops itself
        except (OSError, RuntimeError):
            pass
    if _torchvision_library is None:
        _torchvision_library = torch.library.Library("torchvision", "DEF")
        for schema in _TORCHVISION_SCHEMAS:
            _torchvision_library.define(schema)
    return True


def install_torchvision_cpu_shim() -> None:
    """Run `define_torchvision_ops` when torchvision is first imported (a one-shot import hook;
    costs nothing until then). Called by the CPU install's `.pth` file at interpreter start."""

    class TorchvisionFinder(importlib.abc.MetaPathFinder):
        def find_spec(self, fullname, path, target=None):
            if fullname != "torchvision":
                return None
            sys.meta_path.remove(self)  # once, then the normal finders do the import
            spec = importlib.machinery.PathFinder.find_spec(fullname, path)
            if spec is not None and spec.submodule_search_locations:
                try:
                    define_torchvision_ops(list(spec.submodule_search_locations)[0])
                except Exception as err:  # never break interpreter start-up over this shim
                    print(f"thermal_wild_ns: torchvision CPU shim failed: {err}", file=sys.stderr)
            return None

    if "torchvision" not in sys.modules and not any(type(f).__name__ == "TorchvisionFinder" for f in sys.meta_path):
        sys.meta_path.insert(0, TorchvisionFinder())
