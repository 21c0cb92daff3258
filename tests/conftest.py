import pytest
import torch


def random_scene(n: int, width: int, height: int, seed: int = 0, dtype=torch.float32, device="cpu"):
    """Random Gaussians in front of an identity camera: means, quats, scales, opacities, colors, viewmats, Ks."""
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g, dtype=dtype) * torch.tensor([0.8, 0.6, 0.5], dtype=dtype)
    means[:, 2] += 3.0
    quats = torch.randn(n, 4, generator=g, dtype=dtype)
    scales = torch.rand(n, 3, generator=g, dtype=dtype) * 0.08 + 0.01
    opacities = torch.rand(n, generator=g, dtype=dtype) * 0.9 + 0.05
    colors = torch.rand(n, 1, generator=g, dtype=dtype)
    viewmats = torch.eye(4, dtype=dtype)[None]
    f = 1.1 * width
    Ks = torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], dtype=dtype)[None]
    return [t.to(device) for t in (means, quats, scales, opacities, colors, viewmats, Ks)]


@pytest.fixture(scope="session")
def demo_scene_dir(tmp_path_factory):
    from thermal_wild_ns.data.demo_scene import generate_demo_scene

    return generate_demo_scene(tmp_path_factory.mktemp("demo") / "scene")
