"""The photometric loss of a thermal render against its frame: L1 + (heat-aware) SSIM + the alpha
regulariser, in the training space or taken back to the original space through each frame's
inverse LUT (`loss_space`). Owns what it needs of the frames: each training frame's checks (finite,
contrast, its original-space image), computed once per frame and resolution (the frames never change)."""

from __future__ import annotations

import weakref
from typing import Callable, Dict, Optional, Sequence, Tuple, Union

import numpy as np
import torch
from nerfstudio.utils.rich_utils import CONSOLE
from torch import Tensor, nn

from thermal_wild_ns.image_metrics import ssim
from thermal_wild_ns.model.graphed import GraphedCalls
from thermal_wild_ns.model.losses import alpha_regularizer, heat_aware_ssim, thermal_contrast

GROUND_TRUTH_KEY = "_ground_truth"
"""Where a training step's outputs keep its frame as the loss compares it (`ThermalLoss.frame_of`)."""

INVERSE_LUT_SAMPLES = 4096
"""Training-space values at which each training frame's inverse LUT is tabulated for a loss in
the original space (linear in between: far finer than any step of the equalization)."""


def inverse_lut_table(sequence, frame_times: Sequence[float]) -> Tensor:
    """The inverse LUTs [images, S] of the training frames at capture positions `frame_times`, from
    their `PreprocessedSequence`, sampled at S evenly spaced training-space values."""
    values = np.linspace(0.0, 1.0, INVERSE_LUT_SAMPLES)
    tables = np.stack([sequence.to_original_normalised(values, sequence.lut(int(t))) for t in frame_times])
    return torch.from_numpy(tables.astype(np.float32))  # [images, S]


def checked_thermal_image(batch: Dict) -> Tensor:
    """The batch's image [H, W, 1], or a ValueError saying it is not a single-channel thermal image."""
    image = batch["image"]
    if image.dim() != 3 or image.shape[-1] != 1:
        raise ValueError(
            f"WildThermalModel expects single-channel thermal images [H, W, 1]; image {batch.get('image_idx')} "
            f"has shape {tuple(image.shape)}. Use the thermal datamanager/dataparsers of thermal_wild_ns."
        )
    return image


class ResizedFrames:
    """Training frames at the resolution warm-up's smaller sizes, each resized once per size rather than at
    every visit (splatfacto's `get_gt_img` box-filters the frame at every step, a handful of operations). A
    kept copy serves while the frame asked for is the same tensor, unchanged (its version): the datamanager
    hands each training frame's one tensor again (a frame it copies to the GPU at each visit is resized each
    time, as before). Only the current size's copies are kept, none at full size; the frames themselves are
    not held."""

    def __init__(self) -> None:
        self.scale = 1
        self.kept: Dict[int, Tuple[weakref.ref, int, Tensor]] = {}  # training image -> (its frame, version, resized)

    def get(self, image: int, frame: Tensor, scale: int, resize: Callable[[Tensor], Tensor]) -> Tensor:
        """Training image `image`'s `frame` [H, W, 1] as `resize(frame)` gives it at 1/`scale` of its size."""
        if scale != self.scale:
            self.kept.clear()
            self.scale = scale
        if scale == 1:
            return resize(frame)
        kept = self.kept.get(image)
        if kept is not None and kept[0]() is frame and kept[1] == frame._version:
            return kept[2]
        resized = resize(frame)
        self.kept[image] = (weakref.ref(frame), frame._version, resized)
        return resized


class ThermalLoss(nn.Module):
    """The loss terms of `WildThermalModelConfig` (l1_lambda, ssim_lambda, heat_aware_ssim,
    alpha_lambda, alpha_reg_tolerance, loss_space). `inverse_luts` [images, S] (None: no loss in the
    original space) is a buffer, so it follows the model's device; it is not saved in checkpoints."""

    def __init__(self, config, inverse_luts: Optional[Tensor]):
        super().__init__()
        self.config = config
        self.register_buffer("inverse_luts", inverse_luts, persistent=False)
        self._frame_checks: Dict[tuple, tuple] = {}  # (training image, shape) -> (all finite, contrast, original)
        self._warned_nonfinite = False
        self.graphed = GraphedCalls("loss") if config.graphed_loss else None
        self.resized_frames = ResizedFrames()  # the training frames at the warm-up's sizes: `frame_of`

    def to_original_space(self, values: Tensor, image: int) -> Optional[Tensor]:
        """Training-space values of training image `image` taken back to the original space through
        its inverse LUT (piecewise linear, differentiable); None without inverse LUTs."""
        if self.inverse_luts is None or self.config.loss_space != "original":
            return None
        table = self.inverse_luts[image]  # [S]
        position = values.clamp(0.0, 1.0) * (table.shape[0] - 1)
        lower = position.detach().floor().clamp(max=table.shape[0] - 2)
        weight = position - lower
        lower = lower.long()
        return table[lower] * (1.0 - weight) + table[lower + 1] * weight

    def frame_of(
        self, outputs: Dict, batch: Dict, image: Optional[int], scale: int, resize: Callable[[Tensor], Tensor]
    ) -> Tuple[Tensor, Optional[Tensor]]:
        """The batch's frame at the render's resolution (`resize`, splatfacto's `get_gt_img`, at 1/`scale`) and
        its contrast (`ground_truth`); `image`: its training image in a training step, else None. A training step
        asks twice (its metrics, its loss): the first answer is kept in the step's `outputs`, so the frame is
        resized and checked once per step (a training frame once per size of the warm-up: `ResizedFrames`)."""
        kept = outputs.get(GROUND_TRUTH_KEY)
        if kept is not None:
            return kept
        frame = checked_thermal_image(batch)
        gt = resize(frame) if image is None else self.resized_frames.get(image, frame, scale, resize)
        answer = self.ground_truth(gt, outputs["thermal"], image, batch.get("image_idx"))
        if image is not None:  # a training step's outputs (a render outside training is scored once)
            outputs[GROUND_TRUTH_KEY] = answer
        return answer

    def ground_truth(
        self, gt: Tensor, render: Tensor, image: Optional[int], name: object = None
    ) -> Tuple[Tensor, Optional[Tensor]]:
        """The frame `gt` [H, W, 1] at the render's resolution with non-finite pixels replaced by the
        render (so they add nothing to losses and metrics) and, for a training frame (`image`, its
        index; None otherwise) without such pixels, its thermal contrast (for the heat-aware SSIM).
        `name`: how a warning names the frame (its batch's image index)."""
        key = (image, tuple(gt.shape)) if image is not None else None
        checked = self._frame_checks.get(key) if key is not None else None
        if checked is None:
            all_finite = bool(torch.isfinite(gt).all())
            original = self.to_original_space(gt, image) if key is not None and all_finite else None
            reference = gt if original is None else original
            checked = (all_finite, thermal_contrast(reference) if all_finite else None, original)
            if key is not None:
                self._frame_checks[key] = checked
        all_finite, contrast, _ = checked
        if not all_finite:
            finite = torch.isfinite(gt)
            if not self._warned_nonfinite:
                CONSOLE.log(
                    f"[yellow]Image {name} has {int((~finite).sum())} non-finite pixels; "
                    "they are left out of the loss and metrics."
                )
                self._warned_nonfinite = True
            gt = torch.where(finite, gt, render.detach())
        return gt, contrast

    def forward(
        self, outputs: Dict, gt: Tensor, contrast: Optional[Tensor], image: Optional[int], slot: int = 0
    ) -> Dict[str, Tensor]:
        """The weighted loss terms of `outputs` (thermal, accumulation, background) against `gt`
        (from `ground_truth`); `image`: the training image, None outside training; `slot`: the
        camera's place among a training step's cameras (`GraphedCalls`)."""
        pred = outputs["thermal"]
        cfg = self.config
        compared_pred, compared_gt, l1_scale = pred, gt, 1.0
        if image is not None and cfg.loss_space == "original":
            original = self._frame_checks.get((image, tuple(gt.shape)), (None, None, None))[2]
            if original is not None:
                # L1 in units of the frame's own contrast, so that its weight against the
                # (contrast-relative) SSIM and the alpha term stays what it is in training space
                compared_pred, compared_gt = self.to_original_space(pred, image), original
                l1_scale = 1.0 / contrast
        background = outputs["background"].detach()  # the regulariser cannot move the background
        inputs = (compared_pred, compared_gt.detach(), contrast, outputs["accumulation"], background)
        graphable = image is not None and compared_pred is pred and contrast is not None and torch.is_grad_enabled()
        if self.graphed is not None and graphable:
            terms = self.graphed(None, self.terms, *inputs, slot=slot)  # the training step's: kernels replayed
        else:
            terms = self.terms(*inputs, alpha_target=gt, l1_scale=l1_scale)
        return dict(zip(self.term_names, terms))

    @property
    def term_names(self) -> Tuple[str, ...]:
        return ("l1_loss", "ssim_loss") + (("alpha_loss",) if self.config.alpha_lambda > 0 else ())

    def terms(
        self,
        pred: Tensor,
        gt: Tensor,
        contrast: Optional[Tensor],
        alpha: Tensor,
        background: Tensor,
        alpha_target: Optional[Tensor] = None,
        l1_scale: Union[float, Tensor] = 1.0,
    ) -> Tuple[Tensor, ...]:
        """The weighted terms (`term_names`) of `pred` [H, W, 1] against `gt` [H, W, 1] with the
        render's `alpha` [H, W, 1] and `background` [H, W, 1] (detached); the alpha regulariser
        compares the background with `alpha_target` (the training-space frame; default `gt`). Tensors
        in, tensors out, no host read: a CUDA graph can record them."""
        cfg = self.config
        alpha_target = gt if alpha_target is None else alpha_target
        similarity = heat_aware_ssim(pred, gt, contrast) if cfg.heat_aware_ssim else ssim(pred, gt, data_range=1.0)
        terms = (cfg.l1_lambda * l1_scale * (gt - pred).abs().mean(), cfg.ssim_lambda * (1.0 - similarity))
        if cfg.alpha_lambda > 0:
            terms += (cfg.alpha_lambda * alpha_regularizer(alpha, alpha_target, background, cfg.alpha_reg_tolerance),)
        return terms
