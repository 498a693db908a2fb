"""The one place that knows pyrender 0.1.45's pitfalls (the last release, 2021).

Call :func:`import_pyrender` instead of ``import pyrender``. Before the first
import it:

* picks the OpenGL platform: ``PYOPENGL_PLATFORM=egl`` (Mesa llvmpipe on CPU,
  NVIDIA EGL on GPU) unless the user already set one; when no EGL library can
  be loaded but OSMesa can, it picks ``osmesa``. PyOpenGL reads the variable
  once, at its own import, so the choice cannot change later in a process;
* restores ``np.infty``, which numpy 2 removed and pyrender still uses (mesh
  bounds, shadows);
* leaves pyrender's interactive viewer out: a stand-in takes the place of
  ``pyrender.viewer``, so pyglet (its windowing and GL bindings, ~0.15 CPU-s in
  every process that renders, and a shadow window that would try to open an X
  display) is never imported; nothing here opens a window.

Rules the renderer follows (``render_workers.render.renderer``):

* pyrender's default far plane (100 m) is too short: cameras use zfar=1000,
  the dataset's far limit, and znear=0.1;
* the depth it returns is linear eye-space Z with 0 for background; the
  renderer sets background to 1000 m;
* a ``RenderFlags.SEG`` pass skips every node missing from ``seg_node_map``
  (it then occludes nothing), so the renderer maps every mesh node;
* the first render in a process costs ~1.5 s (context, shader compiling), so a
  renderer is kept alive per worker process.

The passes' changes to pyrender's behaviour live in ``render_workers.render.passes``.
:func:`install_draw_order`: pyrender draws mesh nodes sorted by distance
with ties broken in set (id) order, so coplanar faces could differ between
runs; the renderer gives its own fixed order.

One more pitfall handled here: ``OffscreenRenderer.delete()`` calls
``eglTerminate`` on the EGL display, which is shared by every context of the
process, so deleting one renderer breaks all others; and pyrender's inner
renderer frees its framebuffers again from ``__del__`` in whatever context is
current when the garbage collector runs, which can be another renderer's (same
object names in every context). :func:`delete_offscreen` frees everything once,
in the renderer's own context, and terminates the display only with the last
live renderer.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os
import sys
from types import ModuleType
from typing import Callable

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


class _NoViewer:
    """Stands in for ``pyrender.Viewer``: the interactive viewer is not loaded (:func:`_without_viewer`)."""

    def __init__(self, *args, **kwargs) -> None:
        raise RuntimeError("pyrender's interactive viewer is not loaded in this process "
                           "(render_workers.render.pyrender_setup renders off-screen only)")


def _without_viewer() -> None:
    """pyrender's package imports its viewer (``from .viewer import Viewer``), whose pyglet window and
    GL modules cost ~0.15 CPU-s at every worker's start; a module already in ``sys.modules`` under
    that name is what the import takes instead."""
    if "pyrender" in sys.modules or "pyrender.viewer" in sys.modules:
        return  # imported already (by someone else): as it is
    stand_in = ModuleType("pyrender.viewer", _NoViewer.__doc__)
    stand_in.Viewer = _NoViewer
    sys.modules["pyrender.viewer"] = stand_in


_pyrender: ModuleType | None = None


def import_pyrender() -> ModuleType:
    """Import pyrender with the fixes above applied; ImportError says what to install."""
    global _pyrender
    if _pyrender is not None:
        return _pyrender
    platform = choose_platform()
    _patch_numpy()
    _without_viewer()
    try:
        import pyrender
    except ImportError as exc:
        raise ImportError(f"{_INSTALL_HINT} (import failed: {exc})") from exc
    log.debug("pyrender %s imported with PYOPENGL_PLATFORM=%s", pyrender.__version__, platform)
    _pyrender = pyrender
    return pyrender


_live_renderers = 0


def install_draw_order(offscreen, sorted_mesh_nodes: Callable) -> None:
    """Replace pyrender's distance sort (ties broken in set/id order) on this renderer only."""
    offscreen._renderer._sorted_mesh_nodes = sorted_mesh_nodes


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
    """Free an OffscreenRenderer's OpenGL objects and context, once, in its own context.

    pyrender's ``delete()`` would terminate the EGL display every context of
    the process shares, and its inner renderer frees its buffers a second time
    from ``__del__``, in whatever context is current when the garbage
    collector gets to it: that deleted the shadow framebuffer of a renderer
    still in use. Here the display is terminated only with the last live
    renderer, the inner renderer's later ``__del__`` frees nothing, and the
    context is released so that it is really destroyed.
    """
    global _live_renderers
    inner, platform = getattr(offscreen, "_renderer", None), getattr(offscreen, "_platform", None)
    if inner is None or platform is None:
        return  # already freed
    _live_renderers = max(0, _live_renderers - 1)
    platform.make_current()
    inner.delete()
    inner.delete = _freed  # pyrender's __del__ calls self.delete()
    if hasattr(platform, "_egl_display"):
        from OpenGL import EGL

        display = platform._egl_display
        EGL.eglMakeCurrent(display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, EGL.EGL_NO_CONTEXT)
        if platform._egl_context is not None:
            EGL.eglDestroyContext(display, platform._egl_context)
        if _live_renderers == 0:
            EGL.eglTerminate(display)
        platform._egl_context = platform._egl_display = None
    else:
        platform.delete_context()
    offscreen._renderer = offscreen._platform = None  # its own __del__ then has nothing to free


def _freed() -> None:
    """Stands in for ``delete`` on an inner renderer whose objects are already freed."""
