"""The pure-torch rasterizer: gsplat's rules, exact gradients, densification metadata."""

import math

import pytest
import torch
from conftest import random_scene
from gsplat.cuda._torch_impl import _fully_fused_projection, _quat_scale_to_covar_preci

from thermal_wild_ns.rendering import rasterization, resolve_backend
from thermal_wild_ns.rendering.torch_rasterizer import project_gaussians


def reference_render(means2d, conics, opacities, colors, depths, radii, width, height, tile_size=16):
    """Pixel-by-pixel loop of gsplat's rasterize_to_pixels_fwd.cu (slow, obviously correct)."""
    image = torch.zeros(height, width, colors.shape[-1], dtype=colors.dtype)
    alphas = torch.zeros(height, width, 1, dtype=colors.dtype)
    order = torch.argsort(depths)
    for py in range(height):
        for px in range(width):
            tile = (px // tile_size, py // tile_size)
            T = 1.0
            for g in order.tolist():
                if radii[g] <= 0:
                    continue
                x, y, r = means2d[g, 0].item(), means2d[g, 1].item(), radii[g].item()
                # the splat is listed in this pixel's tile iff its radius box touches the tile
                tx0, tx1 = math.floor((x - r) / tile_size), math.ceil((x + r) / tile_size)
                ty0, ty1 = math.floor((y - r) / tile_size), math.ceil((y + r) / tile_size)
                if not (tx0 <= tile[0] < tx1 and ty0 <= tile[1] < ty1):
                    continue
                dx, dy = x - (px + 0.5), y - (py + 0.5)
                a, b, c = conics[g].tolist()
                sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
                alpha = min(0.999, opacities[g].item() * math.exp(-sigma))
                if sigma < 0 or alpha < 1 / 255:
                    continue
                if T * (1 - alpha) <= 1e-4:
                    break
                image[py, px] += alpha * T * colors[g]
                alphas[py, px] += alpha * T
                T *= 1 - alpha
    return image, alphas


def test_projection_matches_gsplat_reference():
    means, quats, scales, opacities, colors, viewmats, Ks = random_scene(500, 64, 48)
    covars, _ = _quat_scale_to_covar_preci(quats, scales, compute_preci=False)
    ref = _fully_fused_projection(means, covars, viewmats, Ks, 64, 48)
    ours = project_gaussians(means, covars, viewmats, Ks, 64, 48, 0.3, 0.01, 1e10, 0.0, False, "pinhole")
    assert torch.equal(ref[0], ours[0])
    valid = ours[0] > 0
    assert valid.sum() > 100
    for r, o in zip(ref[1:4], ours[1:4]):
        torch.testing.assert_close(o[valid], r[valid], rtol=1e-5, atol=1e-5)


def test_render_matches_pixel_loop():
    width, height = 40, 24  # partial tiles on both axes
    means, quats, scales, opacities, colors, viewmats, Ks = random_scene(
        150, width, height, seed=1, dtype=torch.float64
    )
    image, alphas, meta = rasterization(
        means, quats, scales, opacities, colors, viewmats, Ks, width, height, packed=False
    )
    ref_image, ref_alphas = reference_render(
        meta["means2d"][0], meta["conics"][0], opacities, colors, meta["depths"][0], meta["radii"][0], width, height
    )
    assert image.shape == (1, height, width, 1) and alphas.shape == (1, height, width, 1)
    assert ref_alphas.max() > 0.9  # the scene really occludes
    torch.testing.assert_close(image[0], ref_image, atol=1e-10, rtol=0)
    torch.testing.assert_close(alphas[0], ref_alphas, atol=1e-10, rtol=0)


def test_opaque_deep_stacks_match_pixel_loop():
    """Opacities >= 0.999 in stacks dozens deep: alpha hits gsplat's 0.999 cap and the transmittance
    crosses its 1e-4 cut-off after one or two splats, so both constants decide the image."""
    width, height = 24, 16
    means, quats, scales, opacities, colors, viewmats, Ks = random_scene(
        120, width, height, seed=3, dtype=torch.float64
    )
    opacities = 0.999 + 0.001 * torch.rand(
        len(opacities), generator=torch.Generator().manual_seed(4), dtype=torch.float64
    )
    scales = scales * 3  # wide splats: every pixel sees many of them
    image, alphas, meta = rasterization(
        means, quats, scales, opacities, colors, viewmats, Ks, width, height, packed=False
    )
    ref_image, ref_alphas = reference_render(
        meta["means2d"][0], meta["conics"][0], opacities, colors, meta["depths"][0], meta["radii"][0], width, height
    )
    assert ref_alphas.max() > 0.999 and (ref_alphas > 0.99).float().mean() > 0.5  # really opaque, really stacked
    torch.testing.assert_close(image[0], ref_image, atol=1e-10, rtol=0)
    torch.testing.assert_close(alphas[0], ref_alphas, atol=1e-10, rtol=0)


def test_gradients_are_exact():
    width, height = 20, 18
    means, quats, scales, opacities, colors, viewmats, Ks = random_scene(12, width, height, seed=2, dtype=torch.float64)
    weights = torch.rand(1, height, width, 1, dtype=torch.float64)

    def loss(means, quats, scales, opacities, colors):
        image, alphas, _ = rasterization(
            means, quats, scales, opacities, colors, viewmats, Ks, width, height, packed=False
        )
        return (image * weights).sum() + alphas.sum()

    inputs = tuple(t.clone().requires_grad_() for t in (means, quats, scales, opacities, colors))
    assert torch.autograd.gradcheck(loss, inputs, eps=1e-6, atol=1e-5)


def test_absgrad_is_sum_of_per_pixel_abs_gradients():
    width, height = 20, 20
    scene = random_scene(5, width, height, seed=3, dtype=torch.float64)
    scene[0].requires_grad_()
    image, _, meta = rasterization(*scene, width, height, packed=False, absgrad=True)
    means2d = meta["means2d"]
    means2d.retain_grad()
    image.sum().backward(retain_graph=True)
    absgrad, grad = means2d.absgrad.clone(), means2d.grad.clone()  # before more backward passes
    per_pixel = [
        torch.autograd.grad(image[0, y, x, 0], means2d, retain_graph=True)[0]
        for y in range(height)
        for x in range(width)
    ]
    torch.testing.assert_close(absgrad, sum(g.abs() for g in per_pixel))
    torch.testing.assert_close(grad, sum(per_pixel))
    assert (absgrad > grad.abs() + 1e-6).any()  # abs before the sum really differs


def test_meta_has_what_densification_reads_and_packed_agrees():
    scene = random_scene(300, 64, 48, seed=4)
    for t in scene[:5]:
        t.requires_grad_()
    image, alphas, meta = rasterization(*scene, 64, 48, packed=False, absgrad=True)
    for key in ("means2d", "radii", "width", "height", "n_cameras", "depths", "conics"):
        assert key in meta
    assert meta["radii"].shape == (1, 300) and meta["radii"].dtype == torch.int32
    assert (meta["width"], meta["height"], meta["n_cameras"]) == (64, 48, 1)
    packed_image, packed_alphas, packed_meta = rasterization(*scene, 64, 48, packed=True)
    torch.testing.assert_close(packed_image, image)
    assert packed_meta["means2d"].shape[0] == int((meta["radii"] > 0).sum()) == packed_meta["gaussian_ids"].numel()


def test_depth_modes_and_background():
    scene = random_scene(200, 48, 32, seed=5)
    rgb_ed, alphas, _ = rasterization(
        *scene, 48, 32, packed=False, render_mode="RGB+ED", backgrounds=torch.tensor([[0.25]])
    )
    rgb, _, _ = rasterization(*scene, 48, 32, packed=False)
    assert rgb_ed.shape[-1] == 2
    torch.testing.assert_close(rgb_ed[..., :1], rgb + (1 - alphas) * 0.25)
    covered = alphas[..., 0] > 0.5
    depth = rgb_ed[..., 1][covered]
    assert depth.min() > 1.0 and depth.max() < 6.0  # expected depth lies among the Gaussians' depths


def test_culled_gaussians_do_not_poison_gradients():
    scene = random_scene(50, 32, 32, seed=6)
    scene[0] = scene[0].clone()
    scene[0][:10, 2] = 0.0  # on the camera plane: culled, would divide by zero
    scene[0][10:20, 2] = -2.0  # behind the camera
    scene[0].requires_grad_()
    image, _, meta = rasterization(*scene, 32, 32, packed=False)
    image.sum().backward()
    assert (meta["radii"][0, :20] == 0).all()
    assert torch.isfinite(scene[0].grad).all()


def test_backend_selection():
    assert resolve_backend("auto", torch.device("cpu")) == "torch"
    with pytest.raises(ValueError, match="CUDA"):
        resolve_backend("gsplat", torch.device("cpu"))


@pytest.mark.parametrize("mode", ["classic", "antialiased"])
def test_a_views_splat_weights_render_it_and_its_colours_gradient_as_the_rasterizer(mode):
    from thermal_wild_ns.rendering.backend import FAR_PLANE, NEAR_PLANE, rasterize_unpacked
    from thermal_wild_ns.rendering.splat_weights import splat_weights

    # 50 x 37 pixels: tiles overhang the image on both sides; deep stacks reach the transmittance stop
    means, quats, scales, opacities, colors, viewmats, Ks = random_scene(600, 50, 37, seed=3)
    colors = torch.cat([colors, torch.rand_like(colors)], -1).requires_grad_(True)  # [N, 2]
    render, alpha, _ = rasterize_unpacked(
        means, quats, scales, opacities, colors, viewmats, Ks, 50, 37, True, False, mode, "torch"
    )  # [1, H, W, 3]: two channels and the expected depth
    weights = splat_weights(means, quats, scales, opacities, viewmats, Ks, 50, 37, NEAR_PLANE, FAR_PLANE, mode)
    ours = weights.render(colors)
    assert weights.matrix.shape == (50 * 37, 600) and 0 < weights.matrix._nnz() < 50 * 37 * 600
    assert weights.transposed.shape == (600, 50 * 37)
    torch.testing.assert_close(ours, render, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(weights.alpha, alpha, rtol=1e-5, atol=1e-6)
    upstream = torch.randn_like(render[..., :2])
    (expected,) = torch.autograd.grad((render[..., :2] * upstream).sum(), colors)
    (got,) = torch.autograd.grad((ours[..., :2] * upstream).sum(), colors)
    torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-6)
    # a Gaussian behind the camera has no weight anywhere
    means[0, 2] = -1.0
    behind = splat_weights(means, quats, scales, opacities, viewmats, Ks, 50, 37, NEAR_PLANE, FAR_PLANE, mode)
    assert not (behind.matrix.col_indices() == 0).any()
