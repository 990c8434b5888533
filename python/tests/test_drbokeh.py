"""The Python package against the command line, finite differences and bad input.

Run by scripts/test.sh (after `pip install ./python` into .venv): `.venv/bin/python -m pytest
python/tests`. The command line is the release binary the Rust tests build
(target/release/drbokeh).
"""

import os
import pathlib
import subprocess
import threading
import time
import warnings

os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")

import cv2  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402

import drbokeh  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[2]
BIN = ROOT / "target" / "release" / "drbokeh"
SCENE = ROOT / "examples" / "scene"


def cli(*args, cwd):
    assert BIN.exists(), f"{BIN} is missing: build it with cargo build --release"
    out = subprocess.run([str(BIN), *map(str, args)], cwd=cwd, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return out


def random_layers(h, w, n=2, seed=0):
    """n layers front first: a partly transparent front, an opaque back."""
    rng = np.random.default_rng(seed)
    layers = []
    for k in range(n):
        rgb = rng.uniform(0.05, 1.0, (h, w, 3))
        if k == n - 1:
            a = np.ones((h, w, 1))
        else:
            yy, xx = np.mgrid[0:h, 0:w]
            blob = ((yy - h / 2) ** 2 + (xx - w / 2.5) ** 2) < (min(h, w) / 3) ** 2
            a = np.clip(blob[..., None] * 1.0 + rng.uniform(-0.1, 0.1, (h, w, 1)), 0, 1)
        d = np.full((h, w, 1), 0.8 - 0.6 * k / max(n - 1, 1)) + rng.uniform(-0.05, 0.05, (h, w, 1))
        layers.append(np.concatenate([rgb, a, d], axis=2).astype(np.float32))
    return layers


@pytest.mark.parametrize("kernel,profile", [("auto", "physical"), ("exact", "physical"), ("exact", "official")])
def test_render_layers_equals_the_command_line(tmp_path, kernel, profile):
    layers = random_layers(24, 32, n=2, seed=1)
    names = []
    for k, l in enumerate(layers):
        names.append(f"l{k}.npy")
        np.save(tmp_path / names[-1], l)
    args = ["render"]
    for n in names:
        args += ["--layer", n]
    args += ["--focus", "0.35", "--blur", "6", "--kernel", kernel, "--profile", profile, "-o", "out.npy"]
    cli(*args, cwd=tmp_path)
    want = np.load(tmp_path / "out.npy")
    got = drbokeh.render_layers(layers, 0.35, 6.0, kernel=kernel, profile=profile)
    assert got.shape == (24, 32, 3) and got.dtype == np.float32
    assert np.abs(got - want).max() <= 1e-6
    # Not a trivial pass: the render differs from the layers' plain composite.
    assert np.abs(got - layers[1][..., :3]).max() > 0.05


def bundled_example():
    bgr = cv2.imread(str(SCENE / "image.png"), cv2.IMREAD_UNCHANGED)
    image = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    depth = cv2.imread(str(SCENE / "depth.exr"), cv2.IMREAD_UNCHANGED).astype(np.float32)
    matte = (cv2.imread(str(SCENE / "matte.png"), cv2.IMREAD_UNCHANGED) / 255.0).astype(np.float32)
    return image, depth, matte


def test_render_equals_the_command_line_on_the_bundled_example(tmp_path):
    image, depth, matte = bundled_example()
    cli("render", SCENE / "image.png", "--depth", SCENE / "depth.exr", "--matte", SCENE / "matte.png",
        "--focus-at", "300,118", "--blur", "12", "-o", "out.npy", cwd=tmp_path)
    want = np.load(tmp_path / "out.npy")
    got = drbokeh.render(image, depth, matte=matte, focus_at=(300, 118), blur=12)
    assert got.shape == want.shape == (320, 480, 3)
    assert np.abs(got - want).max() <= 1e-6
    # Without a matte, with the default blur, by focus value: the same as the command line too.
    cli("render", SCENE / "image.png", "--depth", SCENE / "depth.exr", "--focus", "0.2", "-o", "nomatte.npy", cwd=tmp_path)
    got = drbokeh.render(image, depth, focus=0.2)
    assert np.abs(got - np.load(tmp_path / "nomatte.npy")).max() <= 1e-6


def test_build_layers_then_render_layers_is_render():
    image, depth, matte = bundled_example()
    layers = drbokeh.build_layers(image, depth, matte=matte, focus=0.7, blur=10)
    assert len(layers) == 2 and all(l.shape == (320, 480, 5) and l.dtype == np.float32 for l in layers)
    a = drbokeh.render_layers(layers, 0.7, 10.0)
    b = drbokeh.render(image, depth, matte=matte, focus=0.7, blur=10)
    assert np.abs(a - b).max() <= 1e-6


def check_directions(layers, grads, loss, rng, *, eps, tol):
    """The VJP's layer gradients against central differences of `loss(layers)` along three
    random directions in the layers' colour (±1) and disparity (±0.1); alpha only where it is
    inside (0, 1), so no step leaves its domain."""
    for trial in range(3):
        v = [rng.uniform(-1, 1, size=l.shape).astype(np.float32) for l in layers]
        for x, l in zip(v, layers):
            x[..., 3] *= (l[..., 3] > 0.01) & (l[..., 3] < 0.99)
            x[..., 4] *= 0.1
        fd = (loss([l + eps * x for l, x in zip(layers, v)]) - loss([l - eps * x for l, x in zip(layers, v)])) / (2 * eps)
        an = sum(float(np.sum(g.astype(np.float64) * x)) for g, x in zip(grads, v))
        assert abs(fd - an) <= tol * max(abs(fd), abs(an)) + 1e-4, (trial, fd, an)


@pytest.mark.parametrize("seed", [2, 3])
def test_vjp_matches_central_differences(seed):
    rng = np.random.default_rng(seed)
    layers = random_layers(10, 12, n=2, seed=seed)
    focus, blur = 0.45, 4.0
    cot = rng.normal(size=(10, 12, 3)).astype(np.float32)
    # The physical profile's fill rule rounded (as the Rust FD tests do): a hard min() has kinks
    # that central differences straddle.
    smooth = dict(lens=13, edge_width=1.0, fill_width=0.3)
    grads, g_focus, g_blur = drbokeh.render_layers_vjp(layers, focus, blur, cot, **smooth)
    assert len(grads) == 2 and all(g.shape == l.shape for g, l in zip(grads, layers))

    def loss(ls, f, k):
        img = drbokeh.render_layers_differentiable(ls, f, k, **smooth)
        return float(np.sum(img.astype(np.float64) * cot))

    check_directions(layers, grads, lambda ls: loss(ls, focus, blur), rng, eps=2e-3, tol=0.05)
    for name, (f0, k0), step, an in [("focus", (focus, blur), (1e-3, 0), g_focus), ("blur", (focus, blur), (0, 1e-2), g_blur)]:
        fd = (loss(layers, f0 + step[0], k0 + step[1]) - loss(layers, f0 - step[0], k0 - step[1])) / (2 * (step[0] + step[1]))
        assert abs(fd - an) <= 0.05 * max(abs(fd), abs(an)) + 1e-3, (name, fd, an)


def test_aperture_keyword_renders_what_the_command_line_renders(tmp_path):
    """`aperture=` as a shape string or as `[aperture]`'s dict: the render `--aperture ...`
    gives, in `render` and `render_layers`; not the disc's."""
    layers = random_layers(24, 32, n=2, seed=4)
    for k, l in enumerate(layers):
        np.save(tmp_path / f"l{k}.npy", l)
    base = ["render", "--layer", "l0.npy", "--layer", "l1.npy", "--focus", "0.35", "--blur", "8", "--kernel", "exact"]
    cli(*base, "--aperture", "blades:6,rotation=30", "-o", "hex.npy", cwd=tmp_path)
    got = drbokeh.render_layers(layers, 0.35, 8.0, kernel="exact", aperture="blades:6,rotation=30")
    assert np.abs(got - np.load(tmp_path / "hex.npy")).max() <= 1e-6
    disc = drbokeh.render_layers(layers, 0.35, 8.0, kernel="exact")
    assert np.abs(got - disc).max() > 0.01
    cli(*base, "--aperture", "blades:5", "--anamorphic", "1.5", "--chromatic", "0.05", "-o", "five.npy", cwd=tmp_path)
    got = drbokeh.render_layers(layers, 0.35, 8.0, kernel="exact",
                                aperture={"shape": "blades:5", "anamorphic": 1.5, "chromatic": 0.05})
    assert np.abs(got - np.load(tmp_path / "five.npy")).max() <= 1e-6
    image, depth, matte = bundled_example()
    cli("render", SCENE / "image.png", "--depth", SCENE / "depth.exr", "--matte", SCENE / "matte.png", "--focus", "0.7",
        "--blur", "10", "--aperture", "blades:7,curvature=0.3", "--bubble", "0.4", "-o", "photo.npy", cwd=tmp_path)
    got = drbokeh.render(image, depth, matte=matte, focus=0.7, blur=10, aperture={"shape": "blades:7,curvature=0.3", "bubble": 0.4})
    assert np.abs(got - np.load(tmp_path / "photo.npy")).max() <= 1e-6


def test_vjp_through_a_shaped_aperture_matches_differences():
    """The differentiable render through a pentagon with a cat's eye: its VJP against central
    differences of its own forward along random directions (colour, alpha, disparity)."""
    rng = np.random.default_rng(5)
    layers = random_layers(10, 12, n=2, seed=5)
    opts = dict(lens=13, fill_width=0.3, aperture={"shape": "blades:5,rotation=15", "cat_eye": 0.6})
    cot = rng.normal(size=(10, 12, 3)).astype(np.float32)
    grads, _, _ = drbokeh.render_layers_vjp(layers, 0.45, 4.0, cot, **opts)
    disc = drbokeh.render_layers_differentiable(layers, 0.45, 4.0, lens=13, fill_width=0.3)
    assert np.abs(drbokeh.render_layers_differentiable(layers, 0.45, 4.0, **opts) - disc).max() > 0.01

    def loss(ls):
        return float(np.sum(drbokeh.render_layers_differentiable(ls, 0.45, 4.0, **opts).astype(np.float64) * cot))

    check_directions(layers, grads, loss, rng, eps=1e-3, tol=0.02)


def test_bad_apertures_raise():
    layers = random_layers(8, 8, n=1)
    for bad, kind, needle in [("blades:2", ValueError, "blades"), ({"shape": "disc", "roundness": 1}, ValueError, "roundness"),
                              ({"bubble": 3.0}, ValueError, "bubble"), (7, TypeError, "aperture"),
                              ({"bubble": True}, TypeError, "bubble"), ({"anamorphic": float("nan")}, ValueError, "anamorphic")]:
        for call in (lambda: drbokeh.render_layers(layers, 0.5, 4.0, aperture=bad),
                     lambda: drbokeh.render_layers_differentiable(layers, 0.5, 4.0, aperture=bad)):
            with pytest.raises(kind, match=needle):
                call()


def test_dfd_equals_the_command_line(tmp_path):
    """Depth from defocus from Python: the map `drbokeh dfd` writes for the same photos."""
    h, w = 24, 32
    rng = np.random.default_rng(14)
    aif = rng.uniform(0.05, 1.0, (h, w, 3)).astype(np.float32)
    d = np.where(np.arange(w)[None, :] < w // 2, 0.8, 0.4) * np.ones((h, 1))
    layer = np.concatenate([aif, np.ones((h, w, 1)), d[..., None]], axis=2).astype(np.float32)
    bokeh = drbokeh.render_layers([layer], 0.2, 5.0)
    np.save(tmp_path / "aif.npy", aif)
    np.save(tmp_path / "bokeh.npy", bokeh)
    cli("dfd", "aif.npy", "bokeh.npy", "--focus", "0.2", "--blur", "5", "--iters", "15", "--levels", "2", "-o", "d.npy", cwd=tmp_path)
    want = np.load(tmp_path / "d.npy")
    # Focus 0.2 lies inside the disparity range: the library says which side the map keeps.
    with pytest.warns(UserWarning, match="which side|side it started"):
        got = drbokeh.dfd(aif, bokeh, 0.2, 5.0, iters=15, levels=2)
    assert got.shape == (h, w) and got.dtype == np.float32
    assert np.abs(got - want).max() <= 1e-6
    # It moved towards the truth from its start (0.5 everywhere).
    assert np.abs(got - d).mean() < 0.5 * np.abs(0.5 - d).mean()
    with pytest.raises(ValueError, match="iters"):
        drbokeh.dfd(aif, bokeh, 0.2, 5.0, iters=0)
    with pytest.raises(ValueError, match="loss"):
        drbokeh.dfd(aif, bokeh, 0.2, 5.0, loss="l2")


def test_dfd_focal_stack_equals_the_command_line(tmp_path):
    """A list of photos with a list of foci is a focal stack, as `drbokeh dfd AIF B1 B2
    --focus F1 F2`: the same map; no near/far warning (two focal planes tell the sides)."""
    h, w = 24, 32
    rng = np.random.default_rng(21)
    aif = rng.uniform(0.05, 1.0, (h, w, 3)).astype(np.float32)
    d = np.where(np.arange(w)[None, :] < w // 2, 0.2, 0.8) * np.ones((h, 1))
    layer = np.concatenate([aif, np.ones((h, w, 1)), d[..., None]], axis=2).astype(np.float32)
    mid, near = drbokeh.render_layers([layer], 0.5, 6.0), drbokeh.render_layers([layer], 1.0, 6.0)
    for name, img in (("aif", aif), ("mid", mid), ("near", near)):
        np.save(tmp_path / f"{name}.npy", img)
    args = ("--blur", "6", "--iters", "15", "--levels", "2", "-o", "d.npy")
    cli("dfd", "aif.npy", "mid.npy", "near.npy", "--focus", "0.5", "1", *args, cwd=tmp_path)
    want = np.load(tmp_path / "d.npy")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = drbokeh.dfd(aif, [mid, near], [0.5, 1.0], 6.0, iters=15, levels=2)
    assert np.abs(got - want).max() <= 1e-6
    with pytest.raises(ValueError, match="2 defocused photo"):
        drbokeh.dfd(aif, [mid, near], [0.5], 6.0, iters=1)
    with pytest.raises(TypeError, match="list of foci"):
        drbokeh.dfd(aif, (mid, near), 0.5, 6.0, iters=1)


def test_library_warnings_are_python_warnings():
    layers = random_layers(8, 8, n=2, seed=15)
    with pytest.warns(UserWarning, match="focus"):
        drbokeh.render_layers(layers, 1.7, 3.0)


def resident_mb():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


@pytest.mark.skipif(not os.path.exists("/proc/self/statm"), reason="resident memory is read from /proc")
def test_release_memory_hands_back_what_a_render_kept_and_changes_no_result():
    # The extension's allocator keeps a render's freed buffers for the next render (issue 37's
    # overhead); release_memory hands them back, the workers' heaps as well as the caller's.
    # A 600x800 render of two layers frees buffers of tens of MB (each layer 9.6 MB, the
    # compositor's and the kernels' planes as large): after the release the process holds what it
    # held before the render, plus the returned array (5.8 MB) and the allocator's own tables.
    # Measured from a baseline taken after a release, because how much a render's freed pages
    # still count as resident when it returns depends on the machine (the kernel may already
    # have reclaimed some; CI once saw 10 MB where this machine sees 100).
    layers = random_layers(600, 800, n=2, seed=16)
    drbokeh.release_memory()
    base = resident_mb()
    before = drbokeh.render_layers(layers, 0.7, 8.0)
    kept = resident_mb()
    drbokeh.release_memory()
    released = resident_mb()
    assert released - base < 20, (
        f"resident {base:.0f} MB before the render, {kept:.0f} MB after it, {released:.0f} MB after release_memory"
    )
    assert np.isfinite(before).all()  # the returned array survives the release
    assert np.array_equal(drbokeh.render_layers(layers, 0.7, 8.0), before)


def test_the_gil_is_released_while_rust_works():
    layers = random_layers(300, 400, n=2, seed=4)
    count = [0]
    stop = threading.Event()

    def spin():
        while not stop.is_set():
            count[0] += 1

    t = threading.Thread(target=spin)
    t.start()
    time.sleep(0.05)
    before = count[0]
    t0 = time.perf_counter()
    drbokeh.render_layers(layers, 0.9, 20.0, kernel="fast", threads=1)
    took = time.perf_counter() - t0
    during = count[0] - before
    stop.set()
    t.join()
    # Python code ran during the render: with the GIL held it would not have run at all.
    assert took > 0.02, took
    assert during > 1000, (during, took)


def test_non_contiguous_arrays_give_the_same_render():
    layers = random_layers(16, 20, n=2, seed=5)
    want = drbokeh.render_layers(layers, 0.5, 5.0)
    # Fortran order and a strided view of a larger array.
    f = [np.asfortranarray(l) for l in layers]
    big = [np.zeros((32, 40, 5), np.float32) for _ in layers]
    for b, l in zip(big, layers):
        b[::2, ::2] = l
    strided = [b[::2, ::2] for b in big]
    for ls in (f, strided):
        assert not ls[0].flags["C_CONTIGUOUS"]
        assert np.array_equal(drbokeh.render_layers(ls, 0.5, 5.0), want)


def test_layers_are_read_in_place_and_left_unchanged():
    # C-ordered layers are rendered from NumPy's buffer (no copy): a read-only array, a view
    # with an offset into a larger one, and one array given twice render as their copies do,
    # and no call writes to them.
    layers = random_layers(16, 20, n=2, seed=7)
    want = drbokeh.render_layers(layers, 0.5, 5.0)
    big = np.concatenate([np.zeros((3, 20, 5), np.float32), layers[0]], axis=0)
    offset = big[3:]
    assert offset.flags["C_CONTIGUOUS"] and not offset.flags["OWNDATA"]
    frozen = layers[1].copy()
    frozen.flags.writeable = False
    kept = [l.copy() for l in layers]
    assert np.array_equal(drbokeh.render_layers([offset, frozen], 0.5, 5.0), want)
    assert np.array_equal(drbokeh.render_layers([layers[1], layers[1]], 0.5, 5.0),
                          drbokeh.render_layers([layers[1], layers[1].copy()], 0.5, 5.0))
    cot = np.ones((16, 20, 3), np.float32)
    drbokeh.render_layers_vjp(layers, 0.5, 5.0, cot)
    drbokeh.render_layers_differentiable(layers, 0.5, 5.0)
    for a, b in zip(layers, kept):
        assert np.array_equal(a, b)


def test_bad_arrays_raise_and_never_crash():
    good = random_layers(8, 8, n=2, seed=6)
    cases = [
        ([good[0].astype(np.float64), good[1]], TypeError, "float32"),
        ([good[0][..., :4], good[1]], ValueError, "channels"),
        ([good[0], good[1][:4]], ValueError, ""),
        ([np.zeros((0, 8, 5), np.float32)], ValueError, "empty"),
        ([], ValueError, "empty"),
        ([good[0].reshape(-1)], ValueError, "shape"),
        ("not a list of arrays", TypeError, ""),
    ]
    nan = good[1].copy()
    nan[3, 4, 4] = np.nan
    cases.append(([good[0], nan], ValueError, "layers[1]"))
    for layers, exc, needle in cases:
        with pytest.raises(exc) as e:
            drbokeh.render_layers(layers, 0.5, 4.0)
        assert needle in str(e.value), (needle, str(e.value))
    for kwargs, needle in [({"profile": "fancy"}, "profile"), ({"kernel": "magic"}, "kernel"), ({"quality": 0}, "quality"),
                           ({"threads": 0}, "threads")]:
        with pytest.raises(ValueError) as e:
            drbokeh.render_layers(good, 0.5, 4.0, **kwargs)
        assert needle in str(e.value), (kwargs, str(e.value))
    for blur in (float("nan"), -1.0, float("inf")):
        with pytest.raises(ValueError):
            drbokeh.render_layers(good, 0.5, blur)
    with pytest.raises(ValueError):
        drbokeh.render_layers_vjp(good, 0.5, 4.0, np.zeros((8, 8, 2), np.float32))
    image, depth, matte = bundled_example()
    with pytest.raises(ValueError, match="exactly one"):
        drbokeh.render(image, depth, focus=0.5, focus_at=(1, 1))
    with pytest.raises(ValueError, match="aspect"):
        drbokeh.render(image, depth[:, :100], focus=0.5)
    with pytest.raises(OSError):
        drbokeh.render(image, depth, focus=0.5, config="/nonexistent/pipeline.toml")
    with pytest.raises(ValueError, match="layers"):
        drbokeh.render(image, depth, focus=0.5, layers=0)


def test_jax_gives_the_gradient_render_layers_vjp_gives():
    import jax
    import jax.numpy as jnp

    import drbokeh.jax as djax

    layers = random_layers(10, 12, n=2, seed=7)
    rng = np.random.default_rng(7)
    cot = rng.normal(size=(10, 12, 3)).astype(np.float32)
    opts = dict(lens=13, fill_width=0.3)

    def loss(ls, f, k):
        return jnp.sum(djax.render_layers(ls, f, k, **opts) * cot)

    image = djax.render_layers(layers, 0.45, 4.0, **opts)
    assert np.array_equal(np.asarray(image), drbokeh.render_layers_differentiable(layers, 0.45, 4.0, **opts))
    g_layers, g_focus, g_blur = jax.grad(loss, argnums=(0, 1, 2))(tuple(layers), 0.45, 4.0)
    want, want_focus, want_blur = drbokeh.render_layers_vjp(layers, 0.45, 4.0, cot, **opts)
    for g, w in zip(g_layers, want):
        assert np.abs(np.asarray(g) - w).max() <= 1e-4
    assert abs(float(g_focus) - want_focus) <= 1e-4 * max(1.0, abs(want_focus))
    assert abs(float(g_blur) - want_blur) <= 1e-4 * max(1.0, abs(want_blur))
    # jit, and vmap over a batch of scenes: each equals its own render.
    jitted = jax.jit(lambda ls, f, k: djax.render_layers(ls, f, k, **opts))
    assert np.array_equal(np.asarray(jitted(tuple(layers), 0.45, 4.0)), np.asarray(image))
    other = random_layers(10, 12, n=2, seed=8)
    batch = tuple(jnp.stack([a, b]) for a, b in zip(layers, other))
    images = jax.vmap(lambda ls: djax.render_layers(ls, 0.45, 4.0, **opts))(batch)
    assert images.shape == (2, 10, 12, 3)
    assert np.array_equal(np.asarray(images[1]), drbokeh.render_layers_differentiable(other, 0.45, 4.0, **opts))
    grads = jax.vmap(jax.grad(lambda ls: loss(ls, 0.45, 4.0)))(batch)
    want_other, _, _ = drbokeh.render_layers_vjp(other, 0.45, 4.0, cot, **opts)
    assert np.abs(np.asarray(grads[0][1]) - want_other[0]).max() <= 1e-4
    # An aperture dict passes through jit (the options are static, the dict made hashable).
    shaped = dict(opts, aperture={"shape": "blades:6,rotation=15", "anamorphic": 1.3})
    g = jax.jit(jax.grad(lambda ls: jnp.sum(djax.render_layers(ls, 0.45, 4.0, **shaped) * cot)))(tuple(layers))
    want, _, _ = drbokeh.render_layers_vjp(layers, 0.45, 4.0, cot, **shaped)
    assert np.abs(np.asarray(g[0]) - want[0]).max() <= 1e-4 and np.abs(want[0]).max() > 0


def test_jax_example_recovers_a_disparity_map():
    """The README's JAX example: gradient descent on a disparity map through the renderer."""
    import jax
    import jax.numpy as jnp

    import drbokeh.jax as djax

    rng = np.random.default_rng(9)
    h, w = 12, 14
    rgb = rng.uniform(0.1, 1.0, (h, w, 3)).astype(np.float32)
    true_d = (np.where(np.arange(w)[None, :] < w // 2, 0.8, 0.35) * np.ones((h, 1))).astype(np.float32)
    layer = lambda d: jnp.concatenate([rgb, jnp.ones((h, w, 1)), d[..., None]], axis=2)  # noqa: E731
    # Focused behind everything (0.1): the blur grows with d, so the loss tells d's sign.
    focus, blur, opts = 0.1, 3.0, dict(lens=15, fill_width=0.3)
    target = djax.render_layers([layer(jnp.asarray(true_d))], focus, blur, **opts)
    loss = lambda d: jnp.mean((djax.render_layers([layer(d)], focus, blur, **opts) - target) ** 2)  # noqa: E731
    step = jax.jit(jax.value_and_grad(loss))
    # Adam, by hand.
    d = jnp.full((h, w), 0.55, jnp.float32)
    m = v = jnp.zeros_like(d)
    first = None
    for t in range(1, 151):
        value, g = step(d)
        first = first if first is not None else float(value)
        m, v = 0.9 * m + 0.1 * g, 0.999 * v + 0.001 * g * g
        d = jnp.clip(d - 0.02 * (m / (1 - 0.9**t)) / (jnp.sqrt(v / (1 - 0.999**t)) + 1e-8), 0.0, 1.0)
    final = float(loss(d))
    err_start, err_end = float(np.abs(0.55 - true_d).mean()), float(np.abs(np.asarray(d) - true_d).mean())
    print(f"loss {first:.3e} -> {final:.3e}, disparity error {err_start:.3f} -> {err_end:.3f}")
    assert err_end < 0.1 * err_start, (err_start, err_end)
    assert final < 0.1 * first, (first, final)


def test_torch_gives_the_gradient_render_layers_vjp_gives():
    import torch

    import drbokeh.torch as dtorch

    layers = random_layers(10, 12, n=2, seed=10)
    other = random_layers(10, 12, n=2, seed=11)
    cot = np.random.default_rng(10).normal(size=(10, 12, 3)).astype(np.float32)
    opts = dict(lens=13, fill_width=0.3)
    # One scene: autograd's gradients are the Rust VJP's.
    ts = [torch.tensor(l, requires_grad=True) for l in layers]
    focus, blur = torch.tensor(0.45, requires_grad=True), torch.tensor(4.0, requires_grad=True)
    image = dtorch.render_layers(ts, focus, blur, **opts)
    assert np.array_equal(image.detach().numpy(), drbokeh.render_layers_differentiable(layers, 0.45, 4.0, **opts))
    (image * torch.from_numpy(cot)).sum().backward()
    want, want_focus, want_blur = drbokeh.render_layers_vjp(layers, 0.45, 4.0, cot, **opts)
    for t, w in zip(ts, want):
        assert np.abs(t.grad.numpy() - w).max() <= 1e-4
    assert abs(focus.grad.item() - want_focus) <= 1e-4 * max(1.0, abs(want_focus))
    assert abs(blur.grad.item() - want_blur) <= 1e-4 * max(1.0, abs(want_blur))
    # A batch of two scenes: each image and each gradient its own; focus and blur summed.
    batch = [torch.tensor(np.stack([a, b]), requires_grad=True) for a, b in zip(layers, other)]
    focus, blur = torch.tensor(0.45, requires_grad=True), torch.tensor(4.0, requires_grad=True)
    images = dtorch.render_layers(batch, focus, blur, **opts)
    assert images.shape == (2, 10, 12, 3)
    assert np.array_equal(images[1].detach().numpy(), drbokeh.render_layers_differentiable(other, 0.45, 4.0, **opts))
    (images * torch.from_numpy(cot)).sum().backward()
    want_other, of, ob = drbokeh.render_layers_vjp(other, 0.45, 4.0, cot, **opts)
    assert np.abs(batch[0].grad[1].numpy() - want_other[0]).max() <= 1e-4
    assert np.abs(batch[1].grad[0].numpy() - want[1]).max() <= 1e-4
    assert abs(focus.grad.item() - (want_focus + of)) <= 1e-4 * max(1.0, abs(want_focus + of))
    assert abs(blur.grad.item() - (want_blur + ob)) <= 1e-4 * max(1.0, abs(want_blur + ob))
    # The aperture reaches both passes.
    shaped = dict(opts, aperture="blades:7,rotation=15")
    ts = [torch.tensor(l, requires_grad=True) for l in layers]
    (dtorch.render_layers(ts, 0.45, 4.0, **shaped) * torch.from_numpy(cot)).sum().backward()
    want, _, _ = drbokeh.render_layers_vjp(layers, 0.45, 4.0, cot, **shaped)
    assert np.abs(ts[0].grad.numpy() - want[0]).max() <= 1e-4 and np.abs(want[0]).max() > 0


def test_torch_gradients_match_differences_of_its_own_forward():
    """gradcheck in float32: autograd's directional derivative against central differences of
    the wrapper's forward, along random directions (relative 5%, float32 renders)."""
    import torch

    import drbokeh.torch as dtorch

    rng = np.random.default_rng(12)
    layers = [torch.tensor(l) for l in random_layers(9, 11, n=2, seed=12)]
    cot = torch.from_numpy(rng.normal(size=(9, 11, 3)).astype(np.float32))
    opts = dict(lens=11, fill_width=0.3)

    def loss(ls, f, k):
        return float((dtorch.render_layers(ls, f, k, **opts).double() * cot.double()).sum())

    ts = [l.clone().requires_grad_(True) for l in layers]
    f, k = torch.tensor(0.5, requires_grad=True), torch.tensor(3.0, requires_grad=True)
    (dtorch.render_layers(ts, f, k, **opts) * cot).sum().backward()
    for trial in range(3):
        v = [torch.from_numpy(rng.uniform(-1, 1, size=l.shape).astype(np.float32)) for l in layers]
        for x, l in zip(v, layers):
            x[..., 3] *= ((l[..., 3] > 0.01) & (l[..., 3] < 0.99)).float()
            x[..., 4] *= 0.1
        df, dk = float(rng.uniform(-0.1, 0.1)), float(rng.uniform(-1, 1))
        eps = 2e-3
        fd = (loss([l + eps * x for l, x in zip(layers, v)], 0.5 + eps * df, 3.0 + eps * dk)
              - loss([l - eps * x for l, x in zip(layers, v)], 0.5 - eps * df, 3.0 - eps * dk)) / (2 * eps)
        an = sum(float((t.grad.double() * x.double()).sum()) for t, x in zip(ts, v)) + df * f.grad.item() + dk * k.grad.item()
        assert abs(fd - an) <= 0.05 * max(abs(fd), abs(an)) + 1e-4, (trial, fd, an)


def test_torch_example_recovers_a_disparity_map():
    """The README's PyTorch example: torch.optim.Adam on a disparity map through the renderer."""
    import torch

    import drbokeh.torch as dtorch

    rng = np.random.default_rng(9)
    h, w = 12, 14
    rgb = torch.from_numpy(rng.uniform(0.1, 1.0, (h, w, 3)).astype(np.float32))
    true_d = torch.from_numpy((np.where(np.arange(w)[None, :] < w // 2, 0.8, 0.35) * np.ones((h, 1))).astype(np.float32))
    layer = lambda d: torch.cat([rgb, torch.ones(h, w, 1), d[..., None]], dim=2)  # noqa: E731
    opts = dict(lens=15, fill_width=0.3)
    target = dtorch.render_layers([layer(true_d)], 0.1, 3.0, **opts).detach()
    d = torch.full((h, w), 0.55, requires_grad=True)
    opt = torch.optim.Adam([d], lr=0.02)
    for _ in range(150):
        opt.zero_grad()
        loss = ((dtorch.render_layers([layer(d)], 0.1, 3.0, **opts) - target) ** 2).mean()
        loss.backward()
        opt.step()
        with torch.no_grad():
            d.clamp_(0.0, 1.0)
    err_start, err_end = float((0.55 - true_d).abs().mean()), float((d.detach() - true_d).abs().mean())
    print(f"disparity error {err_start:.3f} -> {err_end:.3f}")
    assert err_end < 0.1 * err_start, (err_start, err_end)


def test_torch_bad_tensors_raise():
    import torch

    import drbokeh.torch as dtorch

    good = [torch.tensor(l) for l in random_layers(8, 8, n=2, seed=13)]
    with pytest.raises(TypeError, match="float32"):
        dtorch.render_layers([good[0].double(), good[1]], 0.5, 4.0)
    with pytest.raises(ValueError, match="shape"):
        dtorch.render_layers([good[0][None], good[1]], 0.5, 4.0)
    with pytest.raises(ValueError, match="empty"):
        dtorch.render_layers([], 0.5, 4.0)
    with pytest.raises(TypeError, match="torch.Tensor"):
        dtorch.render_layers([good[0].numpy(), good[1]], 0.5, 4.0)
    bad = good[1].clone()
    bad[2, 2, 0] = float("nan")
    with pytest.raises(ValueError, match="layers\\[1\\]"):
        dtorch.render_layers([good[0], bad], 0.5, 4.0)
