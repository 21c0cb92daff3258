"""Densification with a Gaussian budget: gsplat's DefaultStrategy that never grows past a cap."""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Callable, Hashable, Optional, Tuple

import torch
from gsplat.strategy.ops import remove
from nerfstudio.utils.rich_utils import CONSOLE
from torch import Tensor

from thermal_wild_ns._upstream import DefaultStrategyWithHooks, end_failed_capture

MIN_SCREEN_RADIUS_PX = 2.0
"""The smallest screen radius gsplat's unpacked projection (splatfacto's) gives a visible Gaussian:
ceil(3 sqrt(0.3 + 0.1)) = 2, the 3-sigma radius of the 0.3 px^2 blur (`eps2d`) every projected
covariance gets, plus the 0.1 floor of its eigenvalue spread (fully_fused_projection_fwd.cu; the
torch rasterizer's the same). The packed projection floors the spread at sqrt(0.1), hence 3 px;
`_update_state` leaves packed renders to gsplat."""


def screen_size_rule_applies(width: int, height: int, grow_scale2d: float) -> bool:
    """Whether gsplat's screen-size split rule (radius over `grow_scale2d` of the image's larger
    side) can tell Gaussians apart in a `width` x `height` render. Below MIN_SCREEN_RADIUS_PX /
    grow_scale2d pixels (40 at splatfacto's 0.05) every visible Gaussian passes it, so it splits
    all of them at every refinement (stock splatfacto's 1/4-resolution warm-up on 128x96 frames
    explodes so: docs/design.md)."""
    return max(width, height) * grow_scale2d >= MIN_SCREEN_RADIUS_PX


MEMORY_HEADROOM = 0.85
"""Share of the GPU's memory that growth may plan to fill at a training step's peak."""


def gaussians_memory_holds(n: int, device: torch.device, row_bytes: int) -> Optional[int]:
    """How many more Gaussians the GPU's memory holds next to `n` (None off CUDA): `MEMORY_HEADROOM` of
    the device's memory, less the peak allocation so far and the growth's own transient (it concatenates
    each parameter and its Adam moments anew: twice the widest parameter's `row_bytes` per Gaussian),
    over the peak per Gaussian so far (frames and networks counted in it: it errs towards stopping early)."""
    if device.type != "cuda" or n == 0:
        return None
    total = torch.cuda.get_device_properties(device).total_memory
    peak = torch.cuda.max_memory_allocated(device)
    return max(0, int((MEMORY_HEADROOM * total - peak - 2 * row_bytes * n) / (peak / n)))


def refinement_copies_fit(n: int, device: torch.device, row_bytes: int) -> bool:
    """Whether a pruning's copies fit beside what the GPU holds now (True off CUDA): it copies each
    parameter and its two Adam moments in turn, so up to three times the widest parameter's
    `row_bytes` per Gaussian, on top of the memory allocated between steps, within `MEMORY_HEADROOM`."""
    if device.type != "cuda":
        return True
    total = torch.cuda.get_device_properties(device).total_memory
    return torch.cuda.memory_allocated(device) + 3 * row_bytes * n <= MEMORY_HEADROOM * total


def widest_row_bytes(params) -> int:
    """Bytes of one Gaussian's row in its widest parameter."""
    return max(p[:1].numel() * p.element_size() for p in params.values())


def accumulate_statistics(
    scale: Tensor,
    largest_side: int,
    gradient: Tensor,
    radii: Tensor,
    accepted: Optional[Tensor],
    grad2d: Tensor,
    count: Tensor,
    screen_radii: Optional[Tensor],
) -> None:
    """One render's share of gsplat's densification statistics, added in place: the screen-space
    `gradient` [C, N, 2] of C cameras (or ranks) in pixels (times `scale` [2], as gsplat) into `grad2d`
    [N] and the cameras that see each Gaussian (`radii` [C, N] > 0) into `count` [N], where the divergence
    guard `accepted` the step ([] bool; None: no guard); the largest screen radius over `largest_side`
    into `screen_radii` [N] (None: none recorded at this size). Tensors in, none out, no host read: one
    CUDA graph can record it."""
    grads = gradient * scale  # [C, N, 2] to pixels as gsplat, in one kernel
    visible = radii > 0.0  # [C, N]
    if accepted is not None:
        visible = visible & accepted
    # over the cameras: one camera's row is taken as it is (a view), not reduced over one row (a kernel and a
    # host operation each, at every step), the same values
    over_cameras = (lambda x, reduce: x[0]) if visible.shape[0] == 1 else (lambda x, reduce: reduce(x, 0))
    grad2d += over_cameras(torch.where(visible, grads.norm(dim=-1), 0.0), torch.sum)
    count += over_cameras(visible, torch.sum)
    if screen_radii is not None:  # screen radius normalised to [0, 1], as gsplat
        largest = over_cameras(torch.where(visible, radii, 0), torch.amax)  # [N]
        torch.maximum(screen_radii, largest / float(largest_side), out=screen_radii)


@dataclass(eq=False)
class StatisticsRecording:
    """`accumulate_statistics` recorded as one CUDA graph (`BudgetedDefaultStrategy.graphed`) for one layout
    of its inputs and the state tensors it adds to, held here: the graph writes their memory, and while they
    are held no other tensor takes their place. A step's gradients, radii and verdict are copied into the
    static inputs, then the graph replays: one launch for the kernels a step would launch one by one."""

    layout: Hashable
    kept: Tuple[Optional[Tensor], ...]  # the state's tensors the graph adds to
    inputs: Tuple[Optional[Tensor], ...]  # static: gradient [C, N, 2], radii [C, N], verdict [] (or None)
    graph: torch.cuda.CUDAGraph

    def serves(self, layout: Hashable, kept: Tuple[Optional[Tensor], ...]) -> bool:
        return self.layout == layout and all(a is b for a, b in zip(self.kept, kept))

    def replay(self, inputs: Tuple[Optional[Tensor], ...]) -> None:
        for static, value in zip(self.inputs, inputs):
            if static is not None:
                static.copy_(value)
        self.graph.replay()

    @classmethod
    def record(cls, layout: Hashable, update: Callable, inputs: tuple, kept: tuple) -> "StatisticsRecording":
        """`update` recorded on static copies of `inputs` and on `kept` itself. Its first call (lazy
        initialisations outside the capture) adds to copies of `kept`: the step's share is added once, by
        the replay that follows."""
        static = tuple(None if t is None else t.clone() for t in inputs)
        scratch = tuple(None if t is None else t.clone() for t in kept)
        side = torch.cuda.Stream()
        side.wait_stream(torch.cuda.current_stream())
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.stream(side):
            update(*static, *scratch)
            # what `torch.cuda.graph` does (a capture on a side stream into a private memory pool) without its
            # entry's device sync and `empty_cache`: a recording per refinement would hand the allocator's cache
            # back to the driver every hundred steps, for the next step to allocate again. A capture runs
            # nothing: the state is untouched until the replay
            graph.capture_begin()
            try:
                update(*static, *kept)
            finally:
                graph.capture_end()
        torch.cuda.current_stream().wait_stream(side)
        return cls(layout, kept, static, graph)


@dataclass
class BudgetedDefaultStrategy(DefaultStrategyWithHooks):
    """DefaultStrategy whose growth step keeps only the strongest candidates within `max_gaussians`.

    Candidates are ranked by how far they exceed their growth rule (mean 2D gradient over
    `grow_grad2d`, or screen radius over `grow_scale2d`); the rest are left out of this round
    by masking their statistics before gsplat grows (`before_growth`). Without a cap, small
    images make the screen-size rule split nearly every Gaussian at every refinement.
    """

    max_gaussians: int = 1_000_000
    memory_room: Callable[[int, torch.device, int], Optional[int]] = gaussians_memory_holds
    """How many more Gaussians the device holds (None: no limit known); growth stops there, with a
    message, rather than at an out-of-memory error."""
    memory_stopped_at: Optional[int] = None
    """The Gaussian count at which GPU memory first stopped growth (None: it never did)."""
    copies_fit: Callable[[int, torch.device, int], bool] = refinement_copies_fit
    """Whether a pruning's copies of the parameters fit in GPU memory now; where not, that round
    prunes nothing (with a message) rather than running out of memory halfway through."""
    prunes_skipped: int = 0
    """Refinements whose pruning `copies_fit` turned down (the first one says so on the console)."""
    graphed: bool = False
    """On a GPU, replay the densification statistics of each step as one CUDA graph (`StatisticsRecording`,
    recorded again after each refinement): the same kernels, one launch."""
    _pixel_scales: dict = field(default_factory=dict, repr=False, compare=False)  # `_pixel_scale`'s, by render size
    _statistics: Optional[StatisticsRecording] = field(default=None, repr=False, compare=False)  # the latest
    _statistics_failed: bool = field(default=False, repr=False, compare=False)  # a recording failed: none again

    @classmethod
    def for_splatfacto(cls, cfg, num_train_data: int, ranks: int = 1) -> "BudgetedDefaultStrategy":
        """The strategy of a splatfacto model config (`SplatfactoModelConfig`'s densification fields,
        as splatfacto maps them) with `cfg.max_gaussians` as the budget, shared by `ranks` ranks that
        each hold their share of the Gaussians."""
        return cls(
            max_gaussians=cfg.max_gaussians // ranks,
            prune_opa=cfg.cull_alpha_thresh,
            grow_grad2d=cfg.densify_grad_thresh,
            grow_scale3d=cfg.densify_size_thresh,
            grow_scale2d=cfg.split_screen_size,
            prune_scale3d=cfg.cull_scale_thresh,
            prune_scale2d=cfg.cull_screen_size,
            refine_scale2d_stop_iter=cfg.stop_screen_size_at,
            refine_start_iter=cfg.warmup_length,
            refine_stop_iter=cfg.stop_split_at,
            reset_every=cfg.reset_alpha_every * cfg.refine_every,
            refine_every=cfg.refine_every,
            pause_refine_after_reset=num_train_data + cfg.refine_every,
            absgrad=cfg.use_absgrad,
            revised_opacity=False,
            verbose=False,
            graphed=cfg.graphed_statistics,
        )

    def before_growth(self, params, state, step) -> None:
        n = params["means"].shape[0]
        room = max(self.max_gaussians - n, 0)  # each duplicate or split adds one Gaussian
        fits = self.memory_room(n, params["means"].device, widest_row_bytes(params))
        if fits is not None and fits < room:
            room = fits
            if self.memory_stopped_at is None:
                self.memory_stopped_at = n
                CONSOLE.log(
                    f"[yellow]GPU memory: growth is capped at about {n + fits:,} Gaussians "
                    f"(max_gaussians {self.max_gaussians:,} does not fit); train across GPUs "
                    "(torchrun -m thermal_wild_ns.multi_gpu) or lower the resolution for more"
                )
        grads = state["grad2d"] / state["count"].clamp_min(1)
        score = grads / self.grow_grad2d
        uses_radii = step < self.refine_scale2d_stop_iter  # as in gsplat's _grow_gs
        if uses_radii:
            score = torch.maximum(score, state["radii"] / self.grow_scale2d)
        candidates = score > 1
        if int(candidates.sum()) > room:
            keep = torch.zeros_like(candidates)
            if room > 0:
                keep[torch.topk(torch.where(candidates, score, torch.zeros_like(score)), room).indices] = True
            state["grad2d"] = torch.where(keep, state["grad2d"], torch.zeros_like(state["grad2d"]))
            if uses_radii:
                state["radii"] = torch.where(keep, state["radii"], torch.zeros_like(state["radii"]))

    def refines_at(self, step: int) -> bool:
        """Whether `step_post_backward` grows and prunes at `step` (gsplat 1.4.0's own condition)."""
        return (
            self.refine_start_iter < step < self.refine_stop_iter
            and step % self.refine_every == 0
            and step % self.reset_every >= self.pause_refine_after_reset
        )

    def prune_where(self, params, optimizers, state, mask, step) -> int:
        """Remove the Gaussians where `mask` [N] holds, with their optimizer moments and running statistics, as
        gsplat's own pruning does (and where its copies fit: `prune_allowed`); how many went."""
        n = int(mask.sum())
        if n == 0 or not self.prune_allowed(params, step):
            return 0
        remove(params=params, optimizers=optimizers, state=state, mask=mask)
        return n

    def prune_allowed(self, params, step) -> bool:
        n = params["means"].shape[0]
        if self.copies_fit(n, params["means"].device, widest_row_bytes(params)):
            return True
        self.prunes_skipped += 1
        if self.prunes_skipped == 1:
            CONSOLE.log(
                f"[yellow]step {step}: GPU memory: pruning skipped at {n:,} Gaussians (its copies of the "
                "parameters do not fit); it resumes where memory allows. Train across GPUs (torchrun -m "
                "thermal_wild_ns.multi_gpu) or lower --pipeline.model.max-gaussians for room"
            )
        return False

    def _pixel_scale(self, info, device: torch.device) -> torch.Tensor:
        """[2]: what turns gsplat's screen-space gradients into pixels (its `_update_state`: half the width and
        height, times the cameras), kept per render size on the device (a new tensor would be a copy from
        the host at every step)."""
        key = (info["width"], info["height"], info["n_cameras"], device)
        scale = self._pixel_scales.get(key)
        if scale is None:
            n = info["n_cameras"]
            scale = torch.tensor([info["width"] / 2.0 * n, info["height"] / 2.0 * n], device=device)
            self._pixel_scales[key] = scale
        return scale

    def update_statistics(self, params, state, info, packed: bool) -> bool:
        """gsplat's running statistics, computed with masks instead of gathering the visible
        Gaussians by boolean indexing, which costs two host syncs per step (`accumulate_statistics`; on a
        GPU replayed as one CUDA graph where `graphed`). Identical sums for any number of cameras per
        render, except that a render too small for the screen-size rule (`screen_size_rule_applies`)
        adds no screen radii, and that of several cameras the largest screen radius is kept (gsplat keeps
        whichever camera its indexing writes last). A distributed render (one camera per rank) gives this
        rank's Gaussians in every rank's camera [W, N, ...]: summed as gsplat."""
        if packed:
            return False  # gsplat's own
        if info["radii"].dim() != 2:  # a packed render said to be unpacked would be summed into every Gaussian
            raise ValueError(f"densification statistics: radii {tuple(info['radii'].shape)} are not [C, N]")
        gradient = info[self.key_for_gradient]
        gradient = gradient.absgrad if self.absgrad else gradient.grad  # [C, N, 2], C: cameras or ranks
        n = params["means"].shape[0]
        for key in ("grad2d", "count") + (("radii",) if self.refine_scale2d_stop_iter > 0 else ()):
            if state[key] is None:
                state[key] = torch.zeros(n, device=gradient.device)
        width, height = info["width"], info["height"]
        with_radii = self.refine_scale2d_stop_iter > 0 and screen_size_rule_applies(width, height, self.grow_scale2d)
        inputs = (gradient, info["radii"], info.get("accepted"))
        kept = (state["grad2d"], state["count"], state["radii"] if with_radii else None)
        update = functools.partial(accumulate_statistics, self._pixel_scale(info, gradient.device), max(width, height))
        if self.graphed and gradient.is_cuda:
            # the render size and camera count fix the constants `update` holds (the pixel scale, the side)
            shapes = tuple(None if t is None else (tuple(t.shape), t.dtype) for t in inputs)
            self.recorded_statistics((width, height, info["n_cameras"], shapes), update, inputs, kept)
        else:
            update(*inputs, *kept)
        return True

    def recorded_statistics(self, layout: Hashable, update: Callable, inputs: tuple, kept: tuple) -> None:
        """`update(*inputs, *kept)` replayed as a CUDA graph: recorded once per `layout` (what besides the
        tensors `update` depends on, and the inputs' shapes) and per set of `kept` tensors (the state it adds
        to, replaced at each refinement: one recording per refinement interval); kernel by kernel from the
        first recording that fails on (said once)."""
        recording = self._statistics
        if recording is None or not recording.serves(layout, kept):
            self._statistics = recording = None  # its memory let go before the next is recorded
            if not self._statistics_failed:
                try:
                    recording = StatisticsRecording.record(layout, update, inputs, kept)
                except RuntimeError as error:
                    end_failed_capture()
                    self._statistics_failed = True
                    CONSOLE.log(
                        "[yellow]The densification statistics run kernel by kernel: a CUDA graph could not "
                        f"record them ({error})"
                    )
            self._statistics = recording
        if recording is None:
            update(*inputs, *kept)
        else:
            recording.replay(inputs)
