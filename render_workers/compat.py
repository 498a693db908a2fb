"""The one place that knows pyrender 0.1.45's pitfalls (the last release, 2021).

Call :func:`import_pyrender` instead of ``import pyrender``. Before the first
import it:

* picks the OpenGL platform: ``PYOPENGL_PLATFORM=egl`` (Mesa llvmpipe on CPU,
  NVIDIA EGL on GPU) unless the user already set one; when no EGL library can
  be loaded but OSMesa can, it picks ``osmesa``. PyOpenGL reads the variable
  once, at its own import, so the choice cannot change later in a process;
* restores ``np.infty``, which numpy 2 removed and pyrender still uses (mesh
  bounds, shadows);
* makes pyrender's import-time ``import pyglet`` harmless on a headless machine
  (no shadow window; the viewer is never used).

Rules kept in ``render_workers.renderer`` rather than here:

* pyrender's default far plane (100 m) is too short: cameras use zfar=1000,
  the dataset's far limit, and znear=0.1;
* the depth it returns is linear eye-space Z with 0 for background; the
  renderer sets background to 1000 m;
* a ``RenderFlags.SEG`` pass skips every node missing from ``seg_node_map``
  (it then occludes nothing), so the renderer maps every mesh node;
* pyrender draws mesh nodes sorted by distance with ties broken in set (id)
  order, so coplanar faces could differ between runs; the renderer replaces
  the inner renderer's ``_sorted_mesh_nodes`` with a fixed order, and it swaps
  in a cheaper ``mesh.frag`` (see ``renderer.FAST_MESH_FRAG``);
* the first render in a process costs ~1.5 s (context, shader compiling), so a
  renderer is kept alive per worker process;
* the colour pass always rasterises into a 4x multisampled framebuffer. On
  llvmpipe that costs about half of the colour pass at 1920x1080, so
  :func:`set_msaa_samples` makes the sample count a setting (0 = off; the
  renderer then anti-aliases geometry edges in post, ``postfx.antialias``).

One more pitfall handled here: ``OffscreenRenderer.delete()`` calls
``eglTerminate`` on the EGL display, which is shared by every context of the
process, so deleting one renderer breaks all others. :func:`delete_offscreen`
terminates the display only with the last live renderer.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os
from types import ModuleType

import numpy as np

log = logging.getLogger(__name__)

PLATFORM_VAR = "PYOPENGL_PLATFORM"
_LIBRARIES = {"egl": ("EGL",), "osmesa": ("OSMesa",)}

_INSTALL_HINT = (
    "pyrender is needed to render frames: install it with "
    "`pip install --no-deps pyrender==0.1.45` plus its dependencies "
    "(PyOpenGL>=3.1.7, pyglet, trimesh, freetype-py, imageio, networkx, pillow, scipy, six), "
    "or run `make venv`; headless machines also need Mesa's EGL (libegl1) or OSMesa"
)


def _loadable(platform: str) -> bool:
    for name in _LIBRARIES[platform]:
        path = ctypes.util.find_library(name)
        if path is None:
            continue
        try:
            ctypes.CDLL(path)
        except OSError:
            continue
        return True
    return False


def choose_platform() -> str:
    """Set and return ``PYOPENGL_PLATFORM``: the user's value, else egl, else osmesa."""
    chosen = os.environ.get(PLATFORM_VAR)
    if chosen:
        return chosen
    chosen = "egl"
    if not _loadable("egl") and _loadable("osmesa"):
        chosen = "osmesa"
        log.warning("no EGL library found; falling back to PYOPENGL_PLATFORM=osmesa")
    os.environ[PLATFORM_VAR] = chosen
    return chosen


def _patch_numpy() -> None:
    if not hasattr(np, "infty"):
        np.infty = np.inf  # removed in numpy 2, still used by pyrender 0.1.45


def _quiet_pyglet() -> None:
    try:
        import pyglet
    except ImportError:
        return  # pyrender will say so when it imports pyglet itself
    # pyrender's viewer sets this too, but only after pyglet has been imported;
    # a shadow window would try to open an X display.
    pyglet.options["shadow_window"] = False


_pyrender: ModuleType | None = None


def import_pyrender() -> ModuleType:
    """Import pyrender with the fixes above applied; ImportError says what to install."""
    global _pyrender
    if _pyrender is not None:
        return _pyrender
    platform = choose_platform()
    _patch_numpy()
    _quiet_pyglet()
    try:
        import pyrender
    except ImportError as exc:
        raise ImportError(f"{_INSTALL_HINT} (import failed: {exc})") from exc
    log.debug("pyrender %s imported with PYOPENGL_PLATFORM=%s", pyrender.__version__, platform)
    _pyrender = pyrender
    return pyrender


_live_renderers = 0
_msaa_samples = 4


def set_msaa_samples(samples: int) -> None:
    """Samples of pyrender's colour framebuffer (pyrender hard-codes 4).

    Takes effect when a framebuffer is next configured (new renderer or size).
    """
    global _msaa_samples
    if samples not in (0, 2, 4, 8):
        raise ValueError(f"MSAA samples must be one of 0, 2, 4, 8, got {samples}")
    _msaa_samples = samples
    renderer_module = import_module_attr()
    if not getattr(renderer_module, "_idda_msaa_patched", False):
        original = renderer_module.glRenderbufferStorageMultisample

        def storage(target, _samples, internal_format, width, height):
            return original(target, _msaa_samples, internal_format, width, height)

        renderer_module.glRenderbufferStorageMultisample = storage
        renderer_module._idda_msaa_patched = True


def import_module_attr() -> ModuleType:
    """pyrender's renderer module (where the framebuffer is configured)."""
    import_pyrender()
    import pyrender.renderer

    return pyrender.renderer


def offscreen_renderer(width: int, height: int):
    """A ``pyrender.OffscreenRenderer``; RuntimeError names the platform on failure.

    Free it with :func:`delete_offscreen`, not its own ``delete()``.
    """
    global _live_renderers
    pyrender = import_pyrender()
    try:
        offscreen = pyrender.OffscreenRenderer(viewport_width=width, viewport_height=height)
        _live_renderers += 1
        return offscreen
    except Exception as exc:  # noqa: BLE001 - EGL/OSMesa raise many types
        platform = os.environ.get(PLATFORM_VAR)
        other = "osmesa" if platform == "egl" else "egl"
        raise RuntimeError(
            f"could not create an OpenGL context with {PLATFORM_VAR}={platform} ({exc}); "
            f"install Mesa's EGL (libegl1, libgl1-mesa-dri) or try {PLATFORM_VAR}={other}"
        ) from exc


def delete_offscreen(offscreen) -> None:
    """Free an OffscreenRenderer without terminating the EGL display other renderers use."""
    global _live_renderers
    _live_renderers = max(0, _live_renderers - 1)
    platform = getattr(offscreen, "_platform", None)
    if _live_renderers == 0 or not hasattr(platform, "_egl_display"):
        offscreen.delete()
        return
    from OpenGL.EGL import eglDestroyContext

    platform.make_current()
    offscreen._renderer.delete()
    if platform._egl_context is not None:
        eglDestroyContext(platform._egl_display, platform._egl_context)
    platform._egl_context = platform._egl_display = None
    offscreen._renderer = offscreen._platform = None  # its __del__ then has nothing to free
