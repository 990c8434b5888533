"""``drbokeh.jax.render_layers``: the differentiable render as a JAX function.

The forward is ``drbokeh.render_layers_differentiable`` and the backward
``drbokeh.render_layers_vjp``, both run by the Rust library on the CPU through
``jax.pure_callback`` (no XLA build against the library). ``jax.grad`` gives gradients for
every layer value, the focus and the blur; ``jax.vmap`` maps over a leading batch axis (the
renders run one after the other); ``jax.jit`` works (the callback is a host call).
"""

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from . import _drbokeh

__all__ = ["render_layers"]


def render_layers(layers, focus, blur, *, profile=None, occlusion=True, lens=None, edge_width=1.0, fill_width=0.0, threads=None,
                  aperture=None):
    """Renders ``layers`` (a sequence of H x W x 5 float32 arrays, front first) at ``focus``
    (normalized disparity) and ``blur`` (K), differentiably: H x W x 3 linear RGB.

    The keywords are those of ``drbokeh.render_layers_vjp``; ``lens`` should be given when the
    function is traced under ``vmap`` or ``jit`` with layers whose largest blur differs (the
    default lens window is sized from each call's layers)."""
    layers = tuple(jnp.asarray(l, jnp.float32) for l in layers)
    # Hashable (the options are a static argument): an aperture dict as its sorted items.
    if isinstance(aperture, dict):
        aperture = ("dict", tuple(sorted(aperture.items())))
    opts = (("profile", profile), ("occlusion", occlusion), ("lens", lens), ("edge_width", float(edge_width)),
            ("fill_width", float(fill_width)), ("threads", threads), ("aperture", aperture))
    return _render(layers, jnp.asarray(focus, jnp.float32), jnp.asarray(blur, jnp.float32), opts)


def _kwargs(opts):
    """The keywords of the library's calls from the static options."""
    kw = dict(opts)
    a = kw["aperture"]
    if isinstance(a, tuple) and len(a) == 2 and a[0] == "dict":
        kw["aperture"] = dict(a[1])
    return kw


def _host_layers(ls):
    return [np.ascontiguousarray(l, dtype=np.float32) for l in ls]


@partial(jax.custom_vjp, nondiff_argnums=(3,))
def _render(layers, focus, blur, opts):
    h, w = layers[0].shape[:2]

    def forward(ls, f, k):
        img = _drbokeh.render_layers_differentiable(_host_layers(ls), float(f), float(k), **_kwargs(opts))
        return np.asarray(img, np.float32)

    return jax.pure_callback(forward, jax.ShapeDtypeStruct((h, w, 3), jnp.float32), layers, focus, blur,
                             vmap_method="sequential")


def _render_fwd(layers, focus, blur, opts):
    return _render(layers, focus, blur, opts), (layers, focus, blur)


def _render_bwd(opts, res, cotangent):
    layers, focus, blur = res
    shapes = (tuple(jax.ShapeDtypeStruct(l.shape, jnp.float32) for l in layers),
              jax.ShapeDtypeStruct((), jnp.float32), jax.ShapeDtypeStruct((), jnp.float32))

    def backward(ls, f, k, cot):
        grads, g_focus, g_blur = _drbokeh.render_layers_vjp(_host_layers(ls), float(f), float(k),
                                                            np.ascontiguousarray(cot, dtype=np.float32), **_kwargs(opts))
        return tuple(np.asarray(g, np.float32) for g in grads), np.float32(g_focus), np.float32(g_blur)

    return jax.pure_callback(backward, shapes, layers, focus, blur, cotangent, vmap_method="sequential")


_render.defvjp(_render_fwd, _render_bwd)
