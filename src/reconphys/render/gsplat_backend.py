"""CUDA rasteriser: a thin wrapper around ``gsplat.rasterization`` (gsplat ≥ 1.4, tested 1.5.3).

Same inputs and outputs as :func:`reconphys.render.torch_backend.rasterize_torch`, which is its
pure-PyTorch twin. gsplat's kernels are float32 only: other dtypes are cast to float32 for the call
and the outputs (and, through autograd, the gradients) cast back.
"""

from __future__ import annotations

from torch import Tensor


def rasterize_gsplat(
    means: Tensor,  # [..., N, 3] world frame, metres
    quats: Tensor,  # [..., N, 4] wxyz rotations, not necessarily normalised
    scales: Tensor,  # [..., N, 3] standard deviations, metres
    opacities: Tensor,  # [..., N] in [0, 1]
    colors: Tensor,  # [..., N, D] e.g. RGB in [0, 1]
    world_to_cam: Tensor,  # [..., C, 4, 4] OpenCV convention
    K: Tensor,  # [..., C, 3, 3] pixels
    width: int,
    height: int,
    near_plane: float = 0.01,
    eps2d: float = 0.3,
    antialiased: bool = False,
) -> tuple[Tensor, Tensor, Tensor]:
    """Render with gsplat on CUDA: rgb ``[..., C, H, W, D]``, alpha and depth ``[..., C, H, W]``.

    Calls ``gsplat.rasterization`` with ``packed=False``, ``rasterize_mode="classic"`` (or
    ``"antialiased"`` with ``antialiased``), colours
    given directly (``sh_degree=None``) and ``render_mode="RGB+ED"`` (the last channel is the
    expected camera z, metres). Background black; leading batch dims are passed through (gsplat
    ≥ 1.5 flattens them itself).
    """
    try:
        import gsplat
    except ImportError as error:
        raise ImportError(
            "the 'gsplat' renderer needs the gsplat package and a CUDA GPU "
            "(pip install 'reconphys[gsplat]'); use backend='torch' otherwise"
        ) from error
    tensors = {
        "means": means,
        "quats": quats,
        "scales": scales,
        "opacities": opacities,
        "colors": colors,
        "world_to_cam": world_to_cam,
        "K": K,
    }
    for name, tensor in tensors.items():
        if not tensor.is_cuda:
            raise RuntimeError(
                f"{name}: the 'gsplat' renderer needs CUDA tensors, got device {tensor.device}; "
                "move the Gaussians and cameras to the GPU or use backend='torch'"
            )
    dtype = means.dtype
    as_float = {name: t.float().contiguous() for name, t in tensors.items()}
    render_colors, render_alphas, _ = gsplat.rasterization(
        as_float["means"],
        as_float["quats"],
        as_float["scales"],
        as_float["opacities"],
        as_float["colors"],
        as_float["world_to_cam"],
        as_float["K"],
        width,
        height,
        near_plane=near_plane,
        eps2d=eps2d,
        sh_degree=None,
        packed=False,
        render_mode="RGB+ED",
        rasterize_mode="antialiased" if antialiased else "classic",
    )
    rgb = render_colors[..., :-1].to(dtype)
    depth = render_colors[..., -1].to(dtype)
    alpha = render_alphas[..., 0].to(dtype)
    return rgb, alpha, depth
