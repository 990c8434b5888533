"""drbokeh: occlusion-aware, differentiable lens blur (Dr.Bokeh) on the CPU.

NumPy in, NumPy out. Images are H x W x C float32 arrays (linear RGB unless said); a photo
may also be uint8/uint16 (sRGB, decoded as the command line decodes 8/16-bit files). Layers
are H x W x 5 float32 arrays (straight colour R, G, B; alpha A; normalized disparity D, 0 far
to 1 near), front first. Every function releases the GIL while it works.

- ``render(image, depth, ...)``: the whole pipeline, as ``drbokeh render``.
- ``build_layers(image, depth, ...)``: the layers the pipeline renders.
- ``render_layers(layers, focus, blur, ...)``: as ``drbokeh render --layer``.
- ``render_layers_differentiable`` and ``render_layers_vjp``: the exact kernel's render and its
  vector-Jacobian product (gradients for every layer value, the focus and the blur).
- ``dfd(aif, bokeh, focus, blur, ...)``: depth from defocus, as ``drbokeh dfd``.
- ``drbokeh.torch.render_layers`` and ``drbokeh.jax.render_layers``: the same render as a
  PyTorch autograd function and as a JAX function with a custom VJP (imported on demand).

The library's warnings (a focus clamped into [0, 1], an ignored setting) are ``UserWarning``s.
Errors raise ``ValueError`` (bad arguments or data, with the library's message), ``TypeError``
(an array of the wrong dtype) or ``OSError`` (a config file that cannot be read).
"""

from ._drbokeh import (  # noqa: F401
    __version__,
    build_layers,
    dfd,
    render,
    render_layers,
    render_layers_differentiable,
    render_layers_vjp,
    release_memory,
)

__all__ = [
    "build_layers",
    "dfd",
    "render",
    "render_layers",
    "render_layers_differentiable",
    "render_layers_vjp",
    "release_memory",
]
