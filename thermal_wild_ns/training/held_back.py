"""The frames the automatic stop holds back, and how a model is scored on them: which training images are held
back (`held_back_images`), their score (`held_back_score`: rendered at the state interpolated from the trained
frames around them, PSNR after a gain and offset fitted to each frame, as the `aligned` protocol), and the
trained views the view term's verdict looks at besides (`share_images`, `scene_renders`)."""

from __future__ import annotations

from typing import List, Sequence, Tuple

import numpy as np
import torch

from thermal_wild_ns.image_metrics import psnr
from thermal_wild_ns.pipeline.evaluation import fit_gain_offset, fit_with_radial_falloff
from thermal_wild_ns.pipeline.photometric_state import (
    PhotometricState,
    canonical_state,
    check_same_geometry,
    preprocessed_sequence,
    render,
)
from thermal_wild_ns.training.model_interface import GuardedModel


def held_back_images(num_images: int, count: int) -> Tuple[int, ...]:
    """`count` image indices spread evenly over the interior of `num_images` training images in
    capture order (never the first or the last: their state is interpolated between neighbours).
    Empty for fewer than 10 images per held-back frame: a small capture cannot spare them."""
    if count <= 0 or num_images < 10 * count:
        return ()
    return tuple(int(round((k + 1) * (num_images - 1) / (count + 1))) for k in range(count))


def held_back_score(pipeline, images: Sequence[int], radial: bool = False, canonical: bool = False) -> float:
    """Mean PSNR (original radiometric space, dataset-normalised, range 1: as the evaluation's) of
    the held-back images rendered at the photometric state interpolated from the trained frames
    around them, embedding and LUT alike (`canonical`: at the canonical state, every novel view's),
    after a least-squares gain + offset fit to each frame (`radial`: and a radial fall-off,
    `fit_with_radial_falloff`)."""

    datamanager, model = pipeline.datamanager, pipeline.model
    dataset, sequence = datamanager.train_dataset, preprocessed_sequence(pipeline)
    held_frames = [dataset.frame_index(image) for image in images]  # capture positions
    fill = isinstance(model, GuardedModel) and not canonical
    if fill:
        model.interpolate_embeddings(images)
    shared = canonical_state(pipeline) if canonical else None
    values = []
    for image in images:
        t = dataset.frame_index(image)
        camera = dataset.cameras[image : image + 1].to(model.device)
        if shared is not None:
            state = shared
        else:
            lut = None if sequence is None else sequence.lut_at(t, without=held_frames)
            embedding = model.frame_embed.weight[image].detach() if fill else None
            state = PhotometricState(f"held-back:{t}", embedding, lut)
        _, pred = render(pipeline, camera, state)  # [H, W]
        truth = datamanager.held_back_truth(image)  # [H, W]
        check_same_geometry(pred, truth, f"held-back frame {t}")
        finite = np.isfinite(truth)
        if radial:
            fitted = fit_with_radial_falloff(pred, truth)  # [M]
        else:
            a, b = fit_gain_offset(pred[finite], truth[finite])
            fitted = a * pred[finite] + b
        values.append(float(psnr(torch.from_numpy(fitted), torch.from_numpy(truth[finite]))))
    return float(np.mean(values))


def share_images(num_images: int, held_back: Sequence[int], count: int = 12) -> Tuple[int, ...]:
    """Up to `count` trained image indices spread evenly over the capture (the held-back ones left out):
    the views whose renders show where the view term puts what it adds (`view_probe.radial_share`)."""
    held = set(held_back)
    trained = [k for k in range(num_images) if k not in held]
    if len(trained) <= count:
        return tuple(trained)
    return tuple(trained[round(k * (len(trained) - 1) / (count - 1))] for k in range(count))


def scene_renders(pipeline, images: Sequence[int]) -> List[np.ndarray]:
    """The scene's renders [H, W] (training space, no camera response) of training `images` at the
    canonical state: what the model puts in the scene, the same state in every view."""
    dataset, model, state = pipeline.datamanager.train_dataset, pipeline.model, canonical_state(pipeline)
    return [render(pipeline, dataset.cameras[k : k + 1].to(model.device), state, recorded=False)[0] for k in images]
