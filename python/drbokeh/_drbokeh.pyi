"""Type stubs of the native module (see the package docstring for the conventions)."""

from os import PathLike
from typing import Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float32]
Photo = Union[npt.NDArray[np.float32], npt.NDArray[np.uint8], npt.NDArray[np.uint16]]
Path = Union[str, PathLike]
# A shape as ``--aperture`` spells it ("blades:6,rotation=30", "image:star.png"), or a dict of
# pipeline.toml's [aperture] keys: shape, anamorphic, bubble, chromatic, cat_eye.
Aperture = Union[str, Dict[str, Union[str, float]]]

__version__: str

def render(
    image: Photo,
    depth: Array,
    *,
    matte: Optional[Array] = None,
    focus: Optional[float] = None,
    focus_at: Optional[Tuple[int, int]] = None,
    focus_depth: Optional[float] = None,
    blur: Optional[float] = None,
    depth_kind: str = "depth",
    profile: Optional[str] = None,
    kernel: Optional[str] = None,
    layers: Optional[Union[int, str]] = None,
    config: Optional[Path] = None,
    threads: Optional[int] = None,
    aperture: Optional[Aperture] = None,
) -> Array:
    """The whole pipeline, as ``drbokeh render``: H x W x 3 linear RGB float32.

    image: H x W x 3 (or x 4, or H x W grey) uint8/uint16 sRGB or float32 linear.
    depth: H' x W' float32 of the image's aspect ratio (resized to it); metric depth
    (``depth_kind="depth"``, larger = farther) or disparity (``"disparity"``).
    matte: optional H' x W' float32 in [0, 1], the foreground.
    Exactly one of focus (normalized disparity, 0 far .. 1 near), focus_at=(x, y) (the
    disparity under that pixel) and focus_depth (a metric depth).
    blur: K, the CoC radius in pixels per unit of disparity (default 30 x sqrt(megapixels)).
    profile: "physical" (default) or "official"; kernel: "auto", "fast" or "exact";
    layers: 1..8 or "auto"; config: a pipeline.toml whose settings the keywords override;
    threads: worker threads (default: every core); aperture: the bokeh's shape (default the
    disc; the differentiable renders and dfd take every shape too).
    """

def build_layers(
    image: Photo,
    depth: Array,
    *,
    matte: Optional[Array] = None,
    focus: Optional[float] = None,
    focus_at: Optional[Tuple[int, int]] = None,
    focus_depth: Optional[float] = None,
    blur: Optional[float] = None,
    depth_kind: str = "depth",
    layers: Optional[Union[int, str]] = None,
    config: Optional[Path] = None,
    threads: Optional[int] = None,
) -> List[Array]:
    """The layers the pipeline renders, front first, each H x W x 5 float32 (R, G, B, A, D)."""

def render_layers(
    layers: Sequence[Array],
    focus: float,
    blur: float,
    *,
    profile: Optional[str] = None,
    kernel: Optional[str] = None,
    quality: Optional[int] = None,
    occlusion: Optional[bool] = None,
    lens: Optional[int] = None,
    threads: Optional[int] = None,
    aperture: Optional[Aperture] = None,
) -> Array:
    """Renders given layers as ``drbokeh render --layer``: H x W x 3 linear RGB float32."""

def render_layers_differentiable(
    layers: Sequence[Array],
    focus: float,
    blur: float,
    *,
    profile: Optional[str] = None,
    occlusion: bool = True,
    lens: Optional[int] = None,
    edge_width: float = 1.0,
    fill_width: float = 0.0,
    threads: Optional[int] = None,
    aperture: Optional[Aperture] = None,
) -> Array:
    """The exact kernel's render that ``render_layers_vjp`` differentiates."""

def render_layers_vjp(
    layers: Sequence[Array],
    focus: float,
    blur: float,
    cotangent: Array,
    *,
    profile: Optional[str] = None,
    occlusion: bool = True,
    lens: Optional[int] = None,
    edge_width: float = 1.0,
    fill_width: float = 0.0,
    threads: Optional[int] = None,
    aperture: Optional[Aperture] = None,
) -> Tuple[List[Array], float, float]:
    """(layer_grads, d_focus, d_blur) for the cotangent dL/dimage (H x W x 3)."""

def dfd(
    aif: Photo,
    bokeh: Union[Photo, Sequence[Photo]],
    focus: Union[float, Sequence[float]],
    blur: float,
    *,
    iters: Optional[int] = None,
    levels: Optional[int] = None,
    learning_rate: Optional[float] = None,
    init: Optional[float] = None,
    loss: Optional[str] = None,
    kernel: Optional[str] = None,
    profile: Optional[str] = None,
    occlusion: bool = True,
    threads: Optional[int] = None,
    aperture: Optional[Aperture] = None,
) -> npt.NDArray[np.float32]:
    """Depth from defocus, as ``drbokeh dfd``: the H x W disparity map in [0, 1] that turns the
    all-in-focus photo into ``bokeh`` (focused at ``focus`` with blur ``blur``). A list of
    photos with a list of foci (one per photo) is a focal stack, as ``drbokeh dfd AIF B1 B2
    --focus F1 F2``: two focal planes tell near from far.
    loss: "l1-grad", "l1-grad-ssim" or "l1-grad-hssim" (default); kernel: "auto" (default),
    "fast", "exact" or "ray"; iters per level (default 100), levels (default 3); aperture: the
    lens the photos were taken through (a shape other than the disc runs the exact kernel)."""

def release_memory() -> None:
    """Hands the memory the extension keeps for its next render back to the system (it keeps
    the pages of its largest render between calls, so repeated renders do not map them afresh).
    Returned arrays stay valid; the next render maps what it needs again."""
