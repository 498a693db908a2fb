"""How the renderer changes pyrender's passes, on one renderer instance at a time.

Every change to pyrender's behaviour is made here, by a function that patches
one renderer instance (never pyrender's modules or classes), so renderers with
different settings can live in one process:

* :func:`install_forward_pass`: pyrender sets the camera and every light
  uniform again for each primitive; here once per program and pass (same
  GL state at every draw, ~0.03 CPU-s less per full-HD frame);
* :func:`install_forward_pass` also merges the class pass into the colour
  pass: given a SEG map, a lit pass writes each node's SEG colour into a second
  colour attachment of the (never multisampled) framebuffer and returns
  ``(colour, seg, depth)``: one rasterisation of the scene instead of two
  (~0.03-0.04 CPU-s per full-HD frame), the same values a SEG pass gives;
* pyrender culls back faces in a SEG pass whatever the flags say, while the
  colour pass draws them (``SKIP_CULL_FACES``): a sheet or a leaf seen from
  behind was in the picture and not in the labels (up to 1.4% of a frame's
  pixels in the towns). Here a SEG pass honours ``SKIP_CULL_FACES`` too;
* :func:`install_mesh_shader`: a cheaper ``mesh.frag``
  (``shaders.FAST_MESH_FRAG``) in a shared, content-keyed copy of pyrender's shaders (one per user in the temp dir);
* :func:`install_framebuffer`: the colour pass always rasterises into a 4x
  multisampled framebuffer, which on llvmpipe costs about half of the colour
  pass at 1920x1080; here the sample count is a setting (0 = off; the renderer
  then anti-aliases geometry edges in post, ``postfx.antialias``). pyrender
  also reads back and linearises depth after every pass, with boolean-mask
  indexing, even for the colour pass whose depth the renderer discards; here
  colour passes skip it and depth is linearised in one vectorised pass.

Sun shadows (:func:`install_shadow_pass`, :func:`shadow_texture`) override
private parts of pyrender's inner renderer, on that instance only:

* ``_shadow_mapping_pass`` is replaced. pyrender's version draws every
  ``is_visible`` mesh node with back faces culled into a map fitted around the
  whole scene (``_get_light_cam_matrices`` uses the scene's centroid and
  scale: kilometres for a town, so blurry shadows). The replacement draws the
  caster nodes the renderer chose for the frame (some are culled from the
  view but still cast into it), with no face culling and a slope-scaled
  polygon offset, through the renderer's own light-space matrices;
* ``_get_light_cam_matrices`` returns those same matrices, so the colour pass
  (``_bind_lighting`` sets ``directional_lights[i].light_matrix`` from it)
  samples the map where it was drawn;
* ``_bind_lighting`` is wrapped to also set the renderer's extra shadow
  uniforms (``shadow_params``) that pyrender does not know about;
* the shadow texture is made here rather than by pyrender
  (``DirectionalLight._generate_shadow_texture`` hard-codes 2048 px, nearest
  filtering and repeat wrapping): any size, linear filtering and clamped edges,
  and the pass turns on depth comparison so ``FAST_MESH_FRAG`` samples it as
  a ``sampler2DShadow`` (hardware 2x2 PCF per tap). pyrender's own PBR shader
  reads the map as a plain ``sampler2D``, so comparison is off when it is used.

The SEG pass never takes a shadow pass (pyrender skips it for ``SEG``) and
binds no lights, so class ids and depth do not change with shadows on.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from render_workers.render.pyrender_setup import import_pyrender

MSAA_CHOICES = (0, 2, 4, 8)


def _renderbuffer(GL, fmt, width: int, height: int, samples: int):
    """A renderbuffer of ``fmt``; multisampled with ``samples`` > 0."""
    name = GL.glGenRenderbuffers(1)
    GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, name)
    if samples:
        GL.glRenderbufferStorageMultisample(GL.GL_RENDERBUFFER, samples, fmt, width, height)
    else:
        GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, fmt, width, height)
    return name


def _framebuffer(GL, colour, depth):
    name = GL.glGenFramebuffers(1)
    GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, name)
    GL.glFramebufferRenderbuffer(GL.GL_DRAW_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0, GL.GL_RENDERBUFFER, colour)
    GL.glFramebufferRenderbuffer(GL.GL_DRAW_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT, GL.GL_RENDERBUFFER, depth)
    return name


def _linear_depth(window: np.ndarray, z_near: float, z_far: float | None) -> np.ndarray:
    """pyrender's depth linearisation, step by step in one float32 buffer (same values, fewer passes)."""
    depth = np.multiply(window, 2.0, dtype=np.float32)
    depth -= 1.0  # ndc
    if z_far is None:
        np.subtract(1.0, depth, out=depth)
        np.divide(2 * z_near, depth, out=depth)
    else:
        depth *= z_far - z_near
        np.subtract(z_far + z_near, depth, out=depth)
        np.divide(2.0 * z_near * z_far, depth, out=depth)
    depth[window == 1.0] = 0.0
    return depth


def _read_into(GL, width: int, height: int, fmt, gl_type, out: np.ndarray) -> np.ndarray:
    """The bound read buffer, read straight into ``out`` (a fresh array: the frame owns it), flipped to
    image rows. PyOpenGL's own return value is a bytes copy of the pixels, 2 ms per full-HD read."""
    GL.glReadPixels(0, 0, width, height, fmt, gl_type, out)
    return np.flip(out, axis=0)


def _read_colour(GL, width: int, height: int, fmt, channels: int) -> np.ndarray:
    """The bound read buffer's colour, uint8, flipped to image rows."""
    return _read_into(GL, width, height, fmt, GL.GL_UNSIGNED_BYTE, np.empty((height, width, channels), np.uint8))


def _read_depth(GL, width: int, height: int, scene) -> np.ndarray:
    """The read framebuffer's depth, linearised by the scene camera's planes, flipped to image rows."""
    window = _read_into(GL, width, height, GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT, np.empty((height, width), np.float32))
    camera = scene.main_camera_node.camera
    return _linear_depth(window, camera.znear, camera.zfar)


def _read_framebuffer(GL, RenderFlags, inner, scene, flags):
    """The read-back: resolve the multisampled buffers, then colour and (SEG, depth-only) linear depth."""
    width, height = inner._main_fb_dims
    want_colour = not flags & RenderFlags.DEPTH_ONLY
    want_depth = bool(flags & (RenderFlags.DEPTH_ONLY | RenderFlags.SEG))
    if inner._main_fb_ms != inner._main_fb:
        GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, inner._main_fb_ms)
        GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, inner._main_fb)
        if want_colour:
            GL.glBlitFramebuffer(0, 0, width, height, 0, 0, width, height, GL.GL_COLOR_BUFFER_BIT, GL.GL_LINEAR)
        if want_depth:
            GL.glBlitFramebuffer(0, 0, width, height, 0, 0, width, height, GL.GL_DEPTH_BUFFER_BIT, GL.GL_NEAREST)
    GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, inner._main_fb)
    depth = _read_depth(GL, width, height, scene) if want_depth else None
    if not want_colour:
        return depth
    fmt, channels = (GL.GL_RGBA, 4) if flags & RenderFlags.RGBA else (GL.GL_RGB, 3)
    return _read_colour(GL, width, height, fmt, channels), depth


def _read_merged(GL, inner, scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The read-back of a merged colour pass (never multisampled): colour (RGBA), the labels' SEG
    colours (RGB, from the second attachment) and linear depth, each flipped to image rows."""
    width, height = inner._main_fb_dims
    GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, inner._main_fb)
    GL.glReadBuffer(GL.GL_COLOR_ATTACHMENT1)
    # read as the attachment's RGBA (a copy; RGB makes Mesa repack every pixel: 2 ms more) and used as RGB
    seg = _read_colour(GL, width, height, GL.GL_RGBA, 4)[..., :3]
    GL.glReadBuffer(GL.GL_COLOR_ATTACHMENT0)  # what every other read-back expects
    return _read_colour(GL, width, height, GL.GL_RGBA, 4), seg, _read_depth(GL, width, height, scene)


def install_framebuffer(offscreen, samples: int) -> None:
    """This renderer's main framebuffer and its read-back (pyrender hard-codes 4x MSAA).

    On this instance only: ``samples`` (0 = none) sets the colour framebuffer's
    multisampling; with 0 the passes draw straight into the framebuffer that
    is read, so there is no blit. Colour passes (no ``SEG``, no
    ``DEPTH_ONLY``) return ``(color, None)``: pyrender would read and linearise
    a depth buffer the renderer throws away. Depth is linearised in one
    vectorised pass (pyrender indexes it with boolean masks), same formula,
    same float32 values.
    """
    import_pyrender()
    from OpenGL import GL
    from pyrender.constants import RenderFlags

    if samples not in MSAA_CHOICES:
        raise ValueError(f"MSAA samples must be one of {', '.join(map(str, MSAA_CHOICES))}, got {samples}")
    inner = offscreen._renderer

    def delete():
        if inner._main_fb is not None:
            GL.glDeleteFramebuffers(len({inner._main_fb, inner._main_fb_ms}), list({inner._main_fb, inner._main_fb_ms}))
            buffers = list({inner._main_cb, inner._main_db, inner._main_cb_ms, inner._main_db_ms} - {None})
            buffers += [inner._idda_seg_cb] if inner._idda_seg_cb is not None else []
            GL.glDeleteRenderbuffers(len(buffers), buffers)
        inner._main_fb = inner._main_cb = inner._main_db = None
        inner._main_fb_ms = inner._main_cb_ms = inner._main_db_ms = None
        inner._idda_seg_cb = None

    def configure():
        width, height = inner.viewport_width, inner.viewport_height
        if inner._main_fb is not None and (width, height) != tuple(inner._main_fb_dims):
            delete()
        if inner._main_fb is None:
            inner._main_cb = _renderbuffer(GL, GL.GL_RGBA, width, height, 0)
            inner._main_db = _renderbuffer(GL, GL.GL_DEPTH_COMPONENT24, width, height, 0)
            inner._main_fb = _framebuffer(GL, inner._main_cb, inner._main_db)
            if samples:  # drawn into, then resolved into the plain one by a blit
                inner._main_cb_ms = _renderbuffer(GL, GL.GL_RGBA, width, height, samples)
                inner._main_db_ms = _renderbuffer(GL, GL.GL_DEPTH_COMPONENT24, width, height, samples)
                inner._main_fb_ms = _framebuffer(GL, inner._main_cb_ms, inner._main_db_ms)
            else:
                inner._main_cb_ms, inner._main_db_ms, inner._main_fb_ms = inner._main_cb, inner._main_db, inner._main_fb
                # the labels of a merged colour pass (install_forward_pass): never multisampled, so never blended
                inner._idda_seg_cb = _renderbuffer(GL, GL.GL_RGBA8, width, height, 0)
                GL.glFramebufferRenderbuffer(GL.GL_DRAW_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT1, GL.GL_RENDERBUFFER,
                                             inner._idda_seg_cb)
            inner._main_fb_dims = (width, height)

    inner._idda_seg_cb = None
    inner._configure_main_framebuffer = configure
    inner._delete_main_framebuffer = delete
    inner._read_main_framebuffer = lambda scene, flags: _read_framebuffer(GL, RenderFlags, inner, scene, flags)


def shader_dir(fragment_source: str) -> Path:
    """A directory of pyrender's shaders with ``mesh.frag`` replaced, one per content.

    ``<tmp>/idda-shaders-<uid>/<digest>``, keyed by pyrender's shaders and
    ``fragment_source``. Every renderer with the same shaders shares it, so
    nothing is left behind per renderer (a Ray worker killed at shutdown never
    runs ``atexit``; one temp copy per renderer used to pile up in /tmp). Built
    in a staging directory and renamed into place, so concurrent workers never
    see half of it. RuntimeError if another user owns the directory."""
    pr = import_pyrender()
    sources = sorted((Path(pr.__file__).parent / "shaders").iterdir())
    digest = hashlib.sha256(fragment_source.encode())
    for path in sources:
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    base = Path(tempfile.gettempdir()) / f"idda-shaders-{os.getuid()}"
    base.mkdir(mode=0o700, exist_ok=True)
    if base.stat().st_uid != os.getuid():
        raise RuntimeError(f"{base} belongs to another user; remove it or set TMPDIR")
    final = base / digest.hexdigest()[:16]
    if (final / "mesh.frag").is_file():
        return final
    staging = Path(tempfile.mkdtemp(prefix=f".{final.name}-", dir=base))
    try:
        for path in sources:
            shutil.copy(path, staging / path.name)
        (staging / "mesh.frag").write_text(fragment_source)  # last: its presence marks a complete copy
        try:
            os.rename(staging, final)
        except OSError:  # another process put its identical copy in place first
            pass
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return final


def install_mesh_shader(offscreen, fragment_source: str) -> Path:
    """Point this renderer's shader cache at :func:`shader_dir` (pyrender's shaders with ``mesh.frag`` replaced)."""
    from pyrender.shader_program import ShaderProgramCache

    directory = shader_dir(fragment_source)
    inner = offscreen._renderer  # pyrender keeps its shader cache on the inner renderer
    inner._program_cache.clear()
    inner._program_cache = ShaderProgramCache(shader_dir=str(directory))
    return directory


# GL entry points called per draw, straight through ctypes: PyOpenGL's wrappers convert and check
# every argument (~25-40 us a call; a frame makes ~900 such calls). C types of the arguments, in order.
_INT, _UINT, _SIZE, _BOOL, _PTR = ctypes.c_int, ctypes.c_uint, ctypes.c_int, ctypes.c_ubyte, ctypes.c_void_p
_UNIFORM_ARGS = (_INT, _SIZE, _PTR)  # glUniform{1..4}{f,i,ui}v(location, count, values)
_MATRIX_ARGS = (_INT, _SIZE, _BOOL, _PTR)  # glUniformMatrix{2..4}fv(location, count, transpose, values)
_UNIFORM_SUFFIX = {"f": "f", "i": "i", "u": "ui"}


@functools.cache
def gl_entry(name: str, *argtypes) -> Callable:
    """The GL function ``name`` (void, taking ``argtypes``) as a bare ctypes call: no argument
    conversion and no ``glGetError`` after it (an error stays pending for the next checked call,
    which raises it). Asked of EGL once per process, after a context exists; its address is GL's
    dispatch stub, the same for every context of the process."""
    from OpenGL import platform

    address = platform.PLATFORM.getExtensionProcedure(name.encode())
    if not address:
        raise RuntimeError(f"GL entry point {name} is not available")
    return ctypes.CFUNCTYPE(None, *argtypes)(address)


def draw_primitive(primitive) -> None:
    """Draw a bound primitive (all its instances), as pyrender does."""
    from OpenGL import GL

    instances = 1 if primitive.poses is None else len(primitive.poses)
    if primitive.indices is not None:
        gl_entry("glDrawElementsInstanced", _UINT, _SIZE, _UINT, _PTR, _SIZE)(
            primitive.mode, primitive.indices.size, GL.GL_UNSIGNED_INT, None, instances)
    else:
        gl_entry("glDrawArraysInstanced", _UINT, _INT, _SIZE, _SIZE)(primitive.mode, 0, len(primitive.positions),
                                                                     instances)


def _change(state: dict, key, value, apply: Callable) -> None:
    if key not in state or state[key] != value:
        apply(value)
        state[key] = value


def _set_material(program, material, state: dict) -> None:
    """The material's uniforms, when this program last drew another material (uniform values stay with it)."""
    from pyrender.material import MetallicRoughnessMaterial, SpecularGlossinessMaterial

    if state.get(program) is material:
        return
    set_uniform(program, "material.emissive_factor", material.emissiveFactor)
    if isinstance(material, MetallicRoughnessMaterial):
        set_uniform(program, "material.base_color_factor", material.baseColorFactor)
        set_uniform(program, "material.metallic_factor", material.metallicFactor)
        set_uniform(program, "material.roughness_factor", material.roughnessFactor)
    elif isinstance(material, SpecularGlossinessMaterial):
        set_uniform(program, "material.diffuse_factor", material.diffuseFactor)
        set_uniform(program, "material.specular_factor", material.specularFactor)
        set_uniform(program, "material.glossiness_factor", material.glossinessFactor)
    state[program] = material


def set_uniform(program, name: str, value) -> None:
    """``program.set_uniform(name, value)`` with the uniform's location asked of GL once.

    pyrender's ``ShaderProgram.set_uniform`` asks GL (``glGetUniformLocation``)
    on every call, about a third of a primitive's draw in Python. A location is
    fixed for as long as its program lives, so it is kept on the program object,
    keyed by the GL program it belongs to (pyrender recompiles into the same
    object). The same GL call with the same values follows, as pyrender makes
    it (arrays as float32 vectors or transposed matrices, Python floats and
    ints as scalars), and a name the shader lacks is skipped, as pyrender
    skips it (the fast mesh shader has no metallic factor, for one)."""
    from OpenGL import GL
    from pyrender.shader_program import ShaderProgram

    locations = program.__dict__.setdefault("_idda_locations", {})
    key = (program._program_id, name)
    location = locations.get(key)
    if location is None:
        location = locations[key] = int(GL.glGetUniformLocation(program._program_id, name))
    if location == -1:
        return
    if isinstance(value, np.ndarray):
        if value.ndim == 1:
            kind = value.dtype.kind  # as np.issubdtype decides, without its cost: u unsigned, i signed, else float
            if kind == "u":
                dtype, value = "u", value.astype(np.uint32)
            elif kind == "i":
                dtype, value = "i", value.astype(np.int32)
            else:
                dtype, value = "f", value.astype(np.float32)
            if (value.shape[0], dtype) not in ShaderProgram._FUNC_MAP:  # pyrender has no call for it either
                raise ValueError(f"uniform {name}: no GL call for a vector of {value.shape[0]} {value.dtype}")
            call = f"glUniform{value.shape[0]}{_UNIFORM_SUFFIX[dtype]}v"
            gl_entry(call, *_UNIFORM_ARGS)(location, 1, value.ctypes.data)
        else:
            # square only (pyrender sent a 3x3 as a 4x4; nothing here sets one)
            if value.shape not in ((2, 2), (3, 3), (4, 4)):
                raise ValueError(f"uniform {name}: no GL call for a {value.shape[0]}x{value.shape[1]} matrix")
            matrix = np.ascontiguousarray(value, np.float32)  # what PyOpenGL hands GL for a float matrix
            gl_entry(f"glUniformMatrix{value.shape[0]}fv", *_MATRIX_ARGS)(location, 1, GL.GL_TRUE, matrix.ctypes.data)
    elif isinstance(value, float):
        GL.glUniform1f(location, value)
    elif isinstance(value, int):
        GL.glUniform1i(location, value)
    else:
        raise ValueError(f"uniform {name}: no GL call for a {type(value).__name__}")


def pass_program(inner, programs: dict, primitive, flags, program_flags):
    """pyrender's ``_get_primitive_program``, asked once per kind of primitive in a pass (``programs``:
    the pass's own memo). Its shaders and defines follow from the pass's flags and lights (the same
    for every primitive of a pass) and from what the key holds: buffers, draw mode, material textures
    and kind."""
    material = primitive.material
    key = (flags, program_flags, primitive.buf_flags, primitive.mode, material.tex_flags, type(material))
    program = programs.get(key)
    if program is None:
        program = programs[key] = inner._get_primitive_program(primitive, flags, program_flags)
    return program


def _draw_untextured(inner, primitive, pose, program, flags, state: dict) -> None:
    """pyrender's ``_bind_and_draw_primitive`` for an untextured primitive, with GL state and
    material uniforms issued only when they differ from what this pass last set."""
    from OpenGL import GL
    from pyrender.constants import GLTF, RenderFlags

    set_uniform(program, "M", pose)
    primitive._bind()
    if not (flags & RenderFlags.DEPTH_ONLY or flags & RenderFlags.SEG):
        material = primitive.material
        _set_material(program, material, state)
        blend = (GL.GL_SRC_ALPHA, GL.GL_ONE_MINUS_SRC_ALPHA) if material.alphaMode == "BLEND" else (GL.GL_ONE, GL.GL_ZERO)
        wireframe = material.wireframe != bool(flags & RenderFlags.FLIP_WIREFRAME)
        fill = GL.GL_LINE if flags & RenderFlags.ALL_WIREFRAME or wireframe else GL.GL_FILL
        cull = not (material.doubleSided or flags & RenderFlags.SKIP_CULL_FACES)
    else:  # pyrender culls back faces in depth and SEG passes, whatever the flags say; here a SEG pass
        # draws them when asked (SKIP_CULL_FACES), as the colour pass does, so labels are what it shows
        blend, fill = (GL.GL_ONE, GL.GL_ZERO), GL.GL_FILL
        cull = not (flags & RenderFlags.SEG and flags & RenderFlags.SKIP_CULL_FACES)
    _change(state, "blend", blend, lambda v: (GL.glEnable(GL.GL_BLEND), GL.glBlendFunc(*v)))
    _change(state, "fill", fill, lambda v: GL.glPolygonMode(GL.GL_FRONT_AND_BACK, v))
    _change(state, "cull", cull, lambda v: (GL.glEnable(GL.GL_CULL_FACE), GL.glCullFace(GL.GL_BACK)) if v
            else GL.glDisable(GL.GL_CULL_FACE))
    points = primitive.mode == GLTF.POINTS
    _change(state, "points", points, lambda v: GL.glEnable(GL.GL_PROGRAM_POINT_SIZE) if v
            else GL.glDisable(GL.GL_PROGRAM_POINT_SIZE))
    if points:
        GL.glPointSize(inner.point_size)
    draw_primitive(primitive)


_SEG_CLEAR = (0.0, 0.0, 0.0, 1.0)  # pyrender's clear colour of a SEG pass (background: depth 0, ids 0)


def _clear_for_pass(inner, scene, flags, labels: bool = False) -> bool:
    """Viewport, draw buffers, clear colours and multisampling of a forward pass. ``labels``: a lit
    pass asked to write the labels too, into the second colour attachment, which a framebuffer
    without multisampling has; returns whether it does (a merged pass)."""
    from OpenGL import GL
    from pyrender.constants import RenderFlags

    inner._configure_forward_pass_viewport(flags)
    GL.glDisable(GL.GL_POLYGON_OFFSET_FILL)  # the shadow pass's (a pass cut short leaves it on): a pass sets its own
    seg = bool(flags & RenderFlags.SEG)
    merged = labels and inner._idda_seg_cb is not None
    if merged:
        GL.glDrawBuffers(2, [GL.GL_COLOR_ATTACHMENT0, GL.GL_COLOR_ATTACHMENT1])
        GL.glClearBufferfv(GL.GL_COLOR, 0, np.asarray(scene.bg_color, np.float32))
        GL.glClearBufferfv(GL.GL_COLOR, 1, np.asarray(_SEG_CLEAR, np.float32))
        GL.glClear(GL.GL_DEPTH_BUFFER_BIT)
    else:
        GL.glDrawBuffers(1, [GL.GL_COLOR_ATTACHMENT0])  # a merged pass left two bound on this framebuffer
        GL.glClearColor(*(_SEG_CLEAR if seg else scene.bg_color))
        GL.glClear(GL.GL_COLOR_BUFFER_BIT | GL.GL_DEPTH_BUFFER_BIT)
    if seg:
        GL.glDisable(GL.GL_MULTISAMPLE)
    else:
        GL.glEnable(GL.GL_MULTISAMPLE)
    return merged


def pyrender_binds(tex_flags) -> bool:
    """Whether a lit primitive with these textures takes pyrender's own per-primitive binding (the
    camera, every light and the shadow map set again, then its texture units): any textures but a
    base colour texture alone, which the forward pass binds itself, as pyrender would, to the unit
    after the lights' (~0.3 ms less per textured draw; the towns' ground and walls wear one each)."""
    from pyrender.constants import TexFlags

    return tex_flags not in (TexFlags.NONE, TexFlags.BASE_COLOR)


_NO_LABEL = np.zeros(3)  # a node a merged pass draws but the SEG map lacks: class 0, instance 0


def _seg_color(seg_node_map: dict, node) -> np.ndarray:
    if node not in seg_node_map:
        return _NO_LABEL
    color = seg_node_map[node]
    color = np.repeat(color, 3) if not isinstance(color, (list, tuple, np.ndarray)) else np.asanyarray(color)
    return color / 255.0


def install_forward_pass(offscreen) -> None:
    """pyrender's forward pass with each program's per-pass uniforms set once, on this renderer only.

    pyrender sets the camera (``V``, ``P``, ``cam_pos``) and, in lit passes,
    every light uniform and the shadow map's texture unit again for every
    primitive: about 15 uniform calls through PyOpenGL per primitive, for
    values that are the same for the whole pass (one sun, no light sorting).
    Uniform values stay with their program, so here they are set the first
    time a program is used in a pass; per primitive, the model matrix and the
    draw (uniform locations asked of GL once per program, pyrender's program
    lookup once per kind of primitive in the pass), and the material's
    uniforms and pyrender's blend, polygon, cull and point-size state only
    when they differ from what the pass last set. A
    primitive whose only texture is its base colour gets it on the unit
    pyrender would give it (the one after the shadow map's); one with other
    textures takes pyrender's full per-primitive binding (:func:`pyrender_binds`).
    Same GL state at every draw, so the same pixels.
    """
    import_pyrender()
    from OpenGL import GL
    from pyrender.constants import ProgramFlags, RenderFlags, TexFlags

    inner = offscreen._renderer
    asked = inner._compute_max_n_lights
    max_lights: dict = {}

    def max_n_lights(flags) -> list:
        """pyrender's light limits per program, which it derives for every primitive from a GL query
        (the context's texture units, fixed): asked once per set of flags."""
        if flags not in max_lights:
            max_lights[flags] = tuple(asked(flags))
        return list(max_lights[flags])

    inner._compute_max_n_lights = max_n_lights

    def forward_pass(scene, flags, seg_node_map=None):
        seg = bool(flags & RenderFlags.SEG)
        lit = not (flags & RenderFlags.DEPTH_ONLY or flags & RenderFlags.FLAT or seg)
        # a lit pass given a SEG map draws the labels too (the fast mesh shader's second output)
        merged = _clear_for_pass(inner, scene, flags, labels=lit and seg_node_map is not None)
        seg_node_map = {} if seg and seg_node_map is None else seg_node_map
        V, P = inner._get_camera_matrices(scene)
        cam_pos = scene.get_pose(scene.main_camera_node)[:3, 3]
        ready, program, state, programs = {}, None, {}, {}  # ready: program -> its base colour texture's unit
        for node in inner._sorted_mesh_nodes(scene):
            if not node.mesh.is_visible or (seg and node not in seg_node_map):
                continue
            color = _seg_color(seg_node_map, node) if seg or merged else None
            for primitive in node.mesh.primitives:
                shader = pass_program(inner, programs, primitive, flags, ProgramFlags.USE_MATERIAL)
                if shader is not program:
                    program = shader
                    program._bind()
                tex_flags = primitive.material.tex_flags if lit else TexFlags.NONE
                own = pyrender_binds(tex_flags)
                if own or program not in ready:
                    set_uniform(program, "V", V)
                    set_uniform(program, "P", P)
                    set_uniform(program, "cam_pos", cam_pos)
                    if lit:
                        inner._bind_lighting(scene, program, node, flags)  # the shadow map takes the first units
                    if not own:
                        ready[program] = inner._texture_alloc_idx  # the unit pyrender gives a base colour texture next
                if seg:
                    set_uniform(program, "color", color)
                elif merged:
                    set_uniform(program, "seg_color", color)
                if own:  # pyrender's own binding: texture units, then whatever state it leaves
                    inner._bind_and_draw_primitive(primitive=primitive, pose=scene.get_pose(node), program=program,
                                                   flags=flags)
                    state.clear()
                else:
                    if tex_flags == TexFlags.BASE_COLOR:  # as pyrender's _bind_texture: the unit after the lights'
                        GL.glActiveTexture(GL.GL_TEXTURE0 + ready[program])
                        primitive.material.baseColorTexture._bind()
                        set_uniform(program, "material.base_color_texture", ready[program])
                    _draw_untextured(inner, primitive, scene.get_pose(node), program, flags, state)
                inner._reset_active_textures()
        GL.glBindVertexArray(0)
        if program is not None:
            program._unbind()
        GL.glFlush()
        if merged:
            return _read_merged(GL, inner, scene)
        return inner._read_main_framebuffer(scene, flags) if flags & RenderFlags.OFFSCREEN else None

    inner._forward_pass = forward_pass


# --------------------------------------------------------------------------
# Sun shadows
# --------------------------------------------------------------------------
SHADOW_POLYGON_OFFSET = (2.0, 4.0)  # glPolygonOffset(factor, units) in the shadow pass


@dataclass(eq=False)
class ShadowFrame:
    """What the shadow pass of one frame needs (set by the renderer before each render)."""

    view: np.ndarray  # 4x4 world -> light eye space
    proj: np.ndarray  # 4x4 orthographic light projection
    casters: list  # mesh nodes drawn into the shadow map, in a fixed order
    uniforms: dict = field(default_factory=dict)  # extra colour-pass uniforms, name -> value


def shadow_texture(size: int):
    """A square depth texture for a directional light's shadow map (linear filter, clamped)."""
    pyrender = import_pyrender()
    from OpenGL.GL import GL_FLOAT
    from pyrender.constants import GLTF

    if size < 16 or size & (size - 1):
        raise ValueError(f"shadow map size must be a power of two >= 16, got {size}")
    sampler = pyrender.Sampler(magFilter=GLTF.LINEAR, minFilter=GLTF.LINEAR,
                               wrapS=GLTF.CLAMP_TO_EDGE, wrapT=GLTF.CLAMP_TO_EDGE)
    return pyrender.Texture(sampler=sampler, source_channels="D", width=size, height=size, data_format=GL_FLOAT)


def install_shadow_pass(offscreen, current: Callable[[], ShadowFrame], *, depth_compare: bool = True) -> None:
    """Route pyrender's directional shadow mapping through ``current()`` (see the module notes)."""
    import_pyrender()
    from OpenGL import GL
    from pyrender.constants import ProgramFlags, RenderFlags

    inner = offscreen._renderer
    original_bind_lighting = inner._bind_lighting

    def light_cam_matrices(scene, light_node, flags):
        frame = current()
        return frame.view, frame.proj

    def bind_lighting(scene, program, node, flags):
        original_bind_lighting(scene, program, node, flags)
        if flags & RenderFlags.SHADOWS_DIRECTIONAL:
            for name, value in current().uniforms.items():
                set_uniform(program, name, value)

    def shadow_pass(scene, light_node, flags):
        frame = current()
        texture = light_node.light.shadow_texture
        inner._configure_shadow_framebuffer()
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, inner._shadow_fb)
        GL.glActiveTexture(GL.GL_TEXTURE0)
        texture._bind()
        texture._bind_as_depth_attachment()
        compare = GL.GL_COMPARE_REF_TO_TEXTURE if depth_compare else GL.GL_NONE
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_COMPARE_MODE, compare)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_COMPARE_FUNC, GL.GL_LEQUAL)
        GL.glDrawBuffer(GL.GL_NONE)
        GL.glReadBuffer(GL.GL_NONE)
        GL.glViewport(0, 0, texture.width, texture.height)
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthMask(GL.GL_TRUE)
        GL.glDepthFunc(GL.GL_LESS)
        GL.glDepthRange(0.0, 1.0)
        GL.glClear(GL.GL_DEPTH_BUFFER_BIT)
        GL.glDisable(GL.GL_CULL_FACE)
        GL.glDisable(GL.GL_BLEND)
        GL.glEnable(GL.GL_POLYGON_OFFSET_FILL)
        GL.glPolygonOffset(*SHADOW_POLYGON_OFFSET)
        program, ready, programs = None, set(), {}
        for node in frame.casters:
            pose = scene.get_pose(node)
            for primitive in node.mesh.primitives:
                shader = pass_program(inner, programs, primitive, flags, ProgramFlags.NONE)
                if shader is not program:
                    program = shader
                    program._bind()
                if program not in ready:  # uniform values stay with the program: once per pass
                    set_uniform(program, "V", frame.view)
                    set_uniform(program, "P", frame.proj)
                    ready.add(program)
                set_uniform(program, "M", pose)
                primitive._bind()
                draw_primitive(primitive)
                primitive._unbind()
        if program is not None:
            program._unbind()
        GL.glDisable(GL.GL_POLYGON_OFFSET_FILL)
        GL.glBindTexture(GL.GL_TEXTURE_2D, 0)

    inner._get_light_cam_matrices = light_cam_matrices
    inner._bind_lighting = bind_lighting
    inner._shadow_mapping_pass = shadow_pass
