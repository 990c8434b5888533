"""``drbokeh.torch.render_layers``: the differentiable render as a PyTorch function.

A ``torch.autograd.Function`` whose forward is ``drbokeh.render_layers_differentiable`` and
whose backward is ``drbokeh.render_layers_vjp``, both run by the Rust library on the CPU
(nothing is compiled against libtorch). Layers are CPU float32 tensors, each H x W x 5 or,
for a batch, N x H x W x 5 (the scenes rendered one after the other, the focus and blur shared
by the batch); gradients flow to every layer value, the focus and the blur.
"""

import numpy as np
import torch

from . import _drbokeh

__all__ = ["render_layers"]


def render_layers(layers, focus, blur, *, profile=None, occlusion=True, lens=None, edge_width=1.0, fill_width=0.0, threads=None,
                  aperture=None):
    """Renders ``layers`` (a sequence of H x W x 5, or N x H x W x 5, CPU float32 tensors,
    front first) at ``focus`` (normalized disparity) and ``blur`` (K): H x W x 3 (or
    N x H x W x 3) linear RGB, differentiable with respect to the layers, ``focus`` and
    ``blur`` (floats or 0-d tensors). The keywords are those of ``drbokeh.render_layers_vjp``."""
    layers = list(layers)
    if not layers:
        raise ValueError("layers is empty: give at least one H x W x 5 layer")
    for k, l in enumerate(layers):
        if not isinstance(l, torch.Tensor):
            raise TypeError(f"layers[{k}] must be a torch.Tensor, not {type(l).__name__}")
        if l.device.type != "cpu":
            raise ValueError(f"layers[{k}] is on {l.device}; drbokeh renders on the CPU: move it with .cpu()")
        if l.dtype != torch.float32:
            raise TypeError(f"layers[{k}] must be float32, not {l.dtype}")
        if l.dim() not in (3, 4) or l.dim() != layers[0].dim():
            raise ValueError(f"layers[{k}] has shape {tuple(l.shape)}; expected H x W x 5 (or N x H x W x 5 for every layer)")
    focus = torch.as_tensor(focus, dtype=torch.float32)
    blur = torch.as_tensor(blur, dtype=torch.float32)
    opts = dict(profile=profile, occlusion=occlusion, lens=lens, edge_width=float(edge_width), fill_width=float(fill_width),
                threads=threads, aperture=aperture)
    return _RenderLayers.apply(opts, focus, blur, *layers)


def _scenes(layers):
    """The layers as NumPy arrays, one list per scene of the batch (one scene unbatched)."""
    arrays = [l.detach().contiguous().numpy() for l in layers]
    if arrays[0].ndim == 3:
        return [arrays], False
    return [[a[i] for a in arrays] for i in range(arrays[0].shape[0])], True


class _RenderLayers(torch.autograd.Function):
    @staticmethod
    def forward(ctx, opts, focus, blur, *layers):
        ctx.opts = opts
        ctx.save_for_backward(focus, blur, *layers)
        scenes, batched = _scenes(layers)
        images = [_drbokeh.render_layers_differentiable(s, float(focus), float(blur), **opts) for s in scenes]
        return torch.from_numpy(np.stack(images) if batched else images[0])

    @staticmethod
    def backward(ctx, grad):
        focus, blur, *layers = ctx.saved_tensors
        scenes, batched = _scenes(layers)
        cots = grad.detach().contiguous().numpy()
        cots = list(cots) if batched else [cots]
        per_layer = [[] for _ in layers]
        g_focus = g_blur = 0.0
        for scene, cot in zip(scenes, cots):
            grads, gf, gk = _drbokeh.render_layers_vjp(scene, float(focus), float(blur), np.ascontiguousarray(cot), **ctx.opts)
            for acc, g in zip(per_layer, grads):
                acc.append(g)
            g_focus += gf
            g_blur += gk
        layer_grads = [torch.from_numpy(np.stack(g) if batched else g[0]) for g in per_layer]
        return (None, torch.tensor(g_focus, dtype=torch.float32), torch.tensor(g_blur, dtype=torch.float32), *layer_grads)
