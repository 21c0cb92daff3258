"""One set of evaluation protocols for every method (stock splatfacto included), none of which
lets a held-out frame's pixels into what it scores, except the one labelled oracle.

Every score is in the ORIGINAL radiometric space, dataset-normalised: renders go back through the
LUT of the state they were rendered at; targets are never preprocessed. Two questions, two targets:

- what the scene looks like (`novel`, `aligned`): the held-out view as the dataset gives it, which
  for generated scenes is their clean ground truth (no sensor fault);
- what the camera recorded at that moment (`time`, `half`, `oracle`, the protocols of the frame's
  photometric state): the held-out frame as recorded. A state predicted for a drifting sensor's
  frame carries that drift, so against a fault-free truth it would be scored for the very fault it
  predicts. On real captures both targets are the same frame.

Per held-out view:

- `novel`: the canonical state (`pipeline/photometric_state.py`): what any rendered novel view is.
- `time`: state(t) of the view's capture position, from the neighbouring training frames.
- `aligned`: the `novel` render after a per-view least-squares gain + offset fit to the frame
  (2 numbers per view, the colour-corrected score RawNeRF uses for raw sensor data).
- `half`: the NeRF-W protocol. From the `time` state, the frame embedding is optimised on the LEFT
  half of the frame (mapped to the training space through the time state's LUT), then a gain +
  offset is fitted on the left half; only the RIGHT half is scored. No right-half pixel is read
  before scoring.
- `oracle`: the frame's own LUT (from its own histogram) and an embedding optimised on the whole
  frame: an upper bound of knowing the frame's state. It uses the test pixels: never a headline.
  Scored with it, `oracle_lut`: the `time` state with the frame's own LUT in place of the one
  interpolated from its neighbours. It splits the `time`-`oracle` gap in two: `oracle_lut` - `time`
  is the LUT's share (what a better LUT prediction could gain), `oracle` - `oracle_lut` the embedding's.

Models without frame embeddings or preprocessing have no state to predict: their `novel`, `time`
and `oracle` renders are the same image.
"""

from __future__ import annotations

import contextlib
from functools import partial
from pathlib import Path
from typing import Callable, Dict, Iterator, List, NamedTuple, Optional, Sequence, Tuple, Union

import cv2
import numpy as np
import torch
from nerfstudio.cameras.cameras import Cameras

from thermal_wild_ns.data.palettes import false_colour
from thermal_wild_ns.image_metrics import psnr, squared_centre_distance, ssim
from thermal_wild_ns.pipeline.photometric_state import (
    PhotometricState,
    canonical_state,
    check_same_geometry,
    preprocessed_sequence,
    render,
    state_at,
    to_training_space,
)
from thermal_wild_ns.progress import track

PROTOCOLS = ("novel", "time", "aligned", "half", "oracle")
"""Every protocol `evaluate` scores; `oracle` uses the held-out frame's pixels."""
CHEAP_PROTOCOLS = ("novel", "time", "aligned")
"""The protocols that need no optimisation per view (training curves use these)."""


def fit_gain_offset(pred: np.ndarray, target: np.ndarray) -> Tuple[float, float]:
    """Least-squares (a, b) minimising |a pred + b - target|^2 over the pixels given."""
    p, t = np.asarray(pred, dtype=np.float64).reshape(-1), np.asarray(target, dtype=np.float64).reshape(-1)
    variance = p.var()
    if variance <= 1e-20:  # a flat render: only the offset can be fitted
        return 0.0, float(t.mean())
    a = float(((p - p.mean()) * (t - t.mean())).mean() / variance)
    return a, float(t.mean() - a * p.mean())


def centre_r2(height: int, width: int) -> np.ndarray:
    """Each pixel's squared distance from the image centre [H, W], 1 at the corners: the variable of a
    camera's radial fall-off as the scorers fit it (`fit_with_radial_falloff`, `view_probe.radial_share`)."""
    v, u = np.meshgrid(np.arange(height) + 0.5, np.arange(width) + 0.5, indexing="ij")
    return squared_centre_distance(u, v, width, height)


def fit_with_radial_falloff(pred: np.ndarray, target: np.ndarray) -> np.ndarray:
    """`pred` [H, W] after the least-squares fit to `target` [H, W] (its finite pixels) of a gain, an
    offset and a radial field in r^2 from the image centre, multiplied and added (a + c r^2) pred +
    b + d r^2: what a camera's own fall-off (vignetting) and a frame's level can explain, credited to
    neither render. The fitted values of `target`'s finite pixels [M]."""
    finite = np.isfinite(target)
    p, t, r = (np.asarray(x, dtype=np.float64)[finite] for x in (pred, target, centre_r2(*pred.shape)))  # [M] each
    basis = np.stack([p, np.ones_like(p), r * p, r], axis=1)  # [M, 4]
    coefficients, *_ = np.linalg.lstsq(basis, t, rcond=None)
    return basis @ coefficients


def scores(
    pred: np.ndarray, gt: np.ndarray, to_celsius: Optional[Callable] = None, device: Union[str, torch.device] = "cpu"
) -> Dict[str, float]:
    """PSNR and SSIM of two [H, W] images of the dataset-normalised space (data range 1), computed on `device` (a
    scorer passes its model's: a view's six SSIMs at full resolution belong on its GPU, not on the host); with
    `to_celsius` (the dataset's calibration), the error in °C too: mean absolute, root mean square and the 95th
    percentile of the absolute error over the view's pixels."""

    def tensor(x):
        return torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32)).to(device)[..., None]

    result = {
        "psnr": float(psnr(tensor(pred), tensor(gt))),
        "ssim": float(ssim(tensor(pred), tensor(gt), data_range=1.0)),
    }
    if to_celsius is not None:
        error = np.abs(to_celsius(np.clip(pred, 0.0, 1.0)) - to_celsius(gt))  # [H, W] °C
        error = error[np.isfinite(error)]
        result.update(
            {
                "celsius_mae": float(error.mean()),
                "celsius_rmse": float(np.sqrt((error**2).mean())),
                "celsius_p95": float(np.percentile(error, 95)),
            }
        )
    return result


@contextlib.contextmanager
def parameters_frozen(model: torch.nn.Module) -> Iterator[None]:
    """`model`'s trainable parameters as constants (`requires_grad` off) within the block, trainable again
    after it, however it ends."""
    trainable = [parameter for parameter in model.parameters() if parameter.requires_grad]
    for parameter in trainable:
        parameter.requires_grad_(False)
    try:
        yield
    finally:
        for parameter in trainable:
            parameter.requires_grad_(True)


class Fit(NamedTuple):
    """One held-out view's state fit (`half`, `oracle`): the frame embedding that best explains `target` within
    `columns`, from `start`."""

    camera: Cameras
    target: torch.Tensor  # [H, W] training space
    columns: slice  # the columns the loss sees
    start: torch.Tensor  # [Df]


def fit_embeddings(model, fits: Sequence[Fit], steps: int, lr: float) -> torch.Tensor:
    """The frame embeddings [B, Df] that best explain each fit's target (`Fit`), by Adam on each view's L1 loss
    from its start, every view in one render per step (`model.fitting_views`: on a GPU one rasterization of all
    of them). The views' losses are summed: each embedding's gradient is its own view's and Adam's update is
    elementwise, so each fit ends where it would alone. The model's parameters are constants meanwhile
    (`parameters_frozen`): the render records no graph for the geometry and backward computes the embeddings'
    gradients alone (on a CPU a fraction of the time), leaving training's gradients alone."""
    embeddings = torch.stack([fit.start for fit in fits]).detach().clone().requires_grad_(True)  # [B, Df]
    optimizer = torch.optim.Adam([embeddings], lr=lr)  # a plain leaf: a Parameter would register in the model
    targets = torch.stack([fit.target for fit in fits])  # [B, H, W]
    seen = torch.zeros_like(targets[:, :1])  # [B, 1, W]: each view's loss columns, weighted 1 / their pixels
    for b, fit in enumerate(fits):
        seen[b, :, fit.columns] = 1.0
    seen = seen / (seen.sum(dim=(1, 2), keepdim=True) * targets.shape[1])
    with torch.enable_grad(), parameters_frozen(model):
        views = model.fitting_views([fit.camera for fit in fits])  # the geometry's part of the renders, once
        for _ in range(steps):
            loss = ((views(embeddings) - targets).abs() * seen).sum()  # each view's mean L1 over its columns
            (embeddings.grad,) = torch.autograd.grad(loss, embeddings)
            optimizer.step()
    return embeddings.detach()


def fitted_states(pipeline, fits: Sequence[Tuple[PhotometricState, Optional[Fit]]], steps: int, lr: float, views: int):
    """Each state with its embedding fitted where it has a fit (`fit_embeddings`), `views` held-out views of one
    size per render; the states without a fit (or with no steps) as they are."""
    model, states = pipeline.model, [state for state, _ in fits]
    todo = [k for k, (_, fit) in enumerate(fits) if fit is not None and steps > 0]
    by_size: Dict[Tuple[int, int], List[int]] = {}
    for k in todo:
        by_size.setdefault(tuple(fits[k][1].target.shape), []).append(k)
    chunks = [ks[i : i + views] for ks in by_size.values() for i in range(0, len(ks), views)]
    for chunk in track(chunks, f"Fitting held-out states ({steps} steps, {views} views a render)", min_items=2):
        embeddings = fit_embeddings(model, [fits[k][1] for k in chunk], steps, lr)
        for k, embedding in zip(chunk, embeddings):
            states[k] = PhotometricState(states[k].label, embedding, states[k].lut)
    return states


def half_fit(pipeline, camera, left: np.ndarray, state: PhotometricState) -> Tuple[PhotometricState, Optional[Fit]]:
    """The NeRF-W protocol's state of a view from its LEFT half only (`left`, [H, W // 2] original space): `state`
    and the fit of its embedding on the left half (None: no embedding). The right half is never given, so it
    cannot be read."""
    state = PhotometricState(state.label + "+left-half", state.embedding, state.lut)
    if state.embedding is None:
        return state, None
    device, cols = pipeline.model.device, left.shape[1]
    target = torch.from_numpy(to_training_space(pipeline, left, state)).to(device)
    padded = torch.zeros((target.shape[0], int(camera.width.reshape(-1)[0])), device=device)  # [H, W]
    padded[:, :cols] = target
    return state, Fit(camera, padded, slice(0, cols), state.embedding)


def half_prediction(pipeline, camera, left: np.ndarray, state: PhotometricState) -> np.ndarray:
    """The whole view [H, W] (original space) at the state fitted on its left half (`half_fit`), then a gain +
    offset fitted on the left half."""
    _, pred = render(pipeline, camera, state)
    a, b = fit_gain_offset(pred[:, : left.shape[1]], left)
    return (a * pred + b).astype(np.float32)


def oracle_fit(
    pipeline, camera, frame: int, gt: np.ndarray, start: PhotometricState
) -> Tuple[PhotometricState, Optional[Fit]]:
    """The held-out frame's own state, fitted on ALL its pixels (an upper bound, never a headline): its own LUT,
    and the fit of the embedding on the whole frame (None: no embedding)."""
    sequence = preprocessed_sequence(pipeline)
    lut = None if sequence is None else sequence.oracle_lut(frame)
    state = PhotometricState(f"oracle:{frame}", start.embedding, lut)
    if state.embedding is None:
        return state, None
    target = torch.from_numpy(to_training_space(pipeline, gt, state)).to(pipeline.model.device)
    return state, Fit(camera, target, slice(None), state.embedding)


class HeldOutView(NamedTuple):
    """What the fitted protocols need of a held-out view after the fits (`evaluate`)."""

    camera: Cameras
    frame: int
    recorded: np.ndarray  # [H, W] the frame as recorded, original space
    to_celsius: Optional[Callable]
    time_state: PhotometricState
    time_scores: Optional[Dict[str, float]]


def evaluate(
    pipeline,
    out_dir: Optional[Path] = None,
    protocols=PROTOCOLS,
    fit_steps: int = 100,
    fit_lr: float = 1e-2,
    fit_views: int = 8,
) -> Dict:
    """Mean held-out PSNR/SSIM under each protocol (`psnr_novel`, `ssim_time`, ...; per-view rows in
    `per_view`). The views' `half` and `oracle` fits run after the others' scores, `fit_views` views per render.
    With `out_dir`, a PNG per view: the recorded frame | `time` render | 5x error (inferno); on a calibrated
    capture another in °C (`write_celsius_panel`)."""
    unknown = set(protocols) - set(PROTOCOLS)
    if unknown:
        raise ValueError(f"unknown protocol(s) {sorted(unknown)} (one of {', '.join(PROTOCOLS)})")
    model, datamanager = pipeline.model, pipeline.datamanager
    dataset = datamanager.eval_dataset
    pipeline.eval()
    rng = datamanager.train_dataset.thermal_range
    rows, held_out = [], []
    views = track(
        datamanager.fixed_indices_eval_dataloader,
        f"Scoring held-out views ({', '.join(protocols)})",
        total=len(dataset),
    )
    for i, (camera, batch) in enumerate(views):
        frame = int(dataset.metadata["frame_indices"][int(batch["image_idx"])])
        gt = batch["image"].float().mean(dim=-1).cpu().numpy()  # the held-out view, original space
        recorded = dataset.recorded_image(int(batch["image_idx"]))  # the frame as the camera recorded it
        # a generated scene's held-out view is its clean truth: the scene, with no camera's fall-off in it
        clean_truth = dataset.is_clean_truth(int(batch["image_idx"]))
        row: Dict[str, float] = {"frame": frame}
        # °C errors where the capture is calibrated, through the held-out frame's own calibration
        to_celsius = partial(rng.to_celsius, frame=frame) if rng.has_celsius else None
        novel = None
        if {"novel", "aligned"} & set(protocols):
            _, novel = render(pipeline, camera, canonical_state(pipeline), recorded=not clean_truth)
            check_same_geometry(novel, gt, f"held-out frame {frame}")
        time_state = state_at(pipeline, frame)
        if "novel" in protocols:
            row.update({f"{k}_novel": v for k, v in scores(novel, gt, to_celsius, model.device).items()})
        time_scores = None
        if "time" in protocols or out_dir is not None:
            _, timed = render(pipeline, camera, time_state)
            check_same_geometry(timed, recorded, f"held-out frame {frame} as recorded")
            time_scores = scores(timed, recorded, to_celsius, model.device)
            row.update({f"{k}_time": v for k, v in time_scores.items()})
            if out_dir is not None:
                _write_panel(out_dir / f"test_{i:02d}.png", recorded, timed)
                if to_celsius is not None:
                    recorded_c, timed_c = to_celsius(recorded), to_celsius(np.clip(timed, 0.0, 1.0))
                    write_celsius_panel(out_dir / f"test_{i:02d}_celsius.png", recorded_c, timed_c, f"frame {frame}")
        if "aligned" in protocols:
            a, b = fit_gain_offset(novel, gt)
            row.update({f"{k}_aligned": v for k, v in scores(a * novel + b, gt, to_celsius, model.device).items()})
        rows.append(row)
        held_out.append(HeldOutView(camera, frame, recorded, to_celsius, time_state, time_scores))
    _score_fitted_protocols(pipeline, protocols, held_out, rows, fit_steps, fit_lr, fit_views)
    keys = [k for k in rows[0] if k != "frame"]
    summary = {key: float(np.mean([r[key] for r in rows])) for key in keys}
    return {**summary, "per_view": rows, "gaussians": int(model.num_points)}


def _score_fitted_protocols(pipeline, protocols, held_out: List[HeldOutView], rows: List[Dict], steps, lr, views):
    """`half`, `oracle` and `oracle_lut` of every held-out view into its row: the states fitted first, several
    views per render (`fitted_states`), then each view scored."""
    fits = []  # per view: its left half, and its half's and its oracle's (state, fit), where asked
    for view in held_out:
        left = view.recorded[:, : view.recorded.shape[1] // 2].copy()
        half_job = half_fit(pipeline, view.camera, left, view.time_state) if "half" in protocols else None
        oracle_job = (
            oracle_fit(pipeline, view.camera, view.frame, view.recorded, view.time_state)
            if "oracle" in protocols
            else None
        )
        fits.append((left, half_job, oracle_job))
    jobs = [job for _, *pair in fits for job in pair if job is not None]
    device = pipeline.model.device
    states = iter(fitted_states(pipeline, jobs, steps, lr, views))
    for view, row, (left, half_job, oracle_job) in zip(held_out, rows, fits):
        recorded, to_celsius, half = view.recorded, view.to_celsius, left.shape[1]
        if half_job is not None:
            pred = half_prediction(pipeline, view.camera, left, next(states))
            right = scores(pred[:, half:], recorded[:, half:], to_celsius, device)
            row.update({f"{k}_half": v for k, v in right.items()})
        if oracle_job is not None:
            state = next(states)
            _, pred = render(pipeline, view.camera, state)
            row.update({f"{k}_oracle": v for k, v in scores(pred, recorded, to_celsius, device).items()})
            if state.lut is None and view.time_scores is not None:  # no LUTs: the time state itself, scored
                own_lut_scores = view.time_scores
            else:
                own_lut = PhotometricState(f"oracle-lut:{view.frame}", view.time_state.embedding, state.lut)
                _, pred = render(pipeline, view.camera, own_lut)
                own_lut_scores = scores(pred, recorded, to_celsius, device)
            row.update({f"{k}_oracle_lut": v for k, v in own_lut_scores.items()})


def _write_panel(path: Path, gt: np.ndarray, pred: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    panel = np.concatenate(
        [false_colour(gt), false_colour(pred), false_colour(np.abs(pred - gt) * 5)], 1
    )  # x5: small errors visible
    scale = max(1, 384 // gt.shape[0])
    cv2.imwrite(str(path), cv2.resize(panel, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST))


CELSIUS_ERROR_SCALE = 2.0
"""The °C error panel's full scale (°C): one fixed scale, so that panels of different runs and methods compare."""


def write_celsius_panel(path: Path, recorded: np.ndarray, pred: np.ndarray, title: str) -> np.ndarray:
    """A held-out view in °C: recorded | render (both on the recorded view's 1st–99th percentile span) | |error| on
    0..`CELSIUS_ERROR_SCALE` °C, each labelled with its scale; `recorded` and `pred` [H, W] °C. Returns |error|
    [H, W] °C (NaN where either is not finite)."""
    finite = np.isfinite(recorded) & np.isfinite(pred)
    error = np.where(finite, np.abs(pred - recorded), np.nan)
    low, high = np.percentile(recorded[finite], [1, 99]) if finite.any() else (0.0, 1.0)
    span = max(float(high - low), 1e-6)
    scale = max(1, 384 // recorded.shape[0])
    mae = float(np.nanmean(error)) if finite.any() else float("nan")
    tiles = []
    for top, label in (  # cv2's font has no degree sign
        ((recorded - low) / span, f"{title}: recorded {low:.1f} to {high:.1f} C"),
        ((pred - low) / span, "render, same scale"),
        (error / CELSIUS_ERROR_SCALE, f"|error| 0 to {CELSIUS_ERROR_SCALE:g} C, MAE {mae:.2f} C"),
    ):
        tile = false_colour(np.nan_to_num(top, nan=0.0))
        tile = cv2.resize(tile, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
        strip = np.zeros((22, tile.shape[1], 3), np.uint8)
        cv2.putText(strip, label, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(np.concatenate([strip, tile], 0))
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.concatenate(tiles, 1))
    return error
