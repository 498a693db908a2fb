"""Low-poly primitives and procedural vertex colours for the world builders.

Every primitive returns plain ``(vertices, faces)`` arrays (float64 (N, 3),
int64 (M, 3)); faces wind counter-clockwise seen from outside. Faces never
share vertices across a crease, so smooth shading of the merged meshes stays
flat where it should.

Colours are computed from positions with a hashed value noise, never from a
random generator, so the same geometry always gets the same bytes.

``MeshBatch`` collects primitives per key ``(tile, class_id, material, texture)`` and
turns them into a few large :class:`render_workers.worlds.scene.Part` objects.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import trimesh

from render_workers.worlds.scene import Part

TILE_M = 200.0  # edge of the spatial tiles static geometry is split into

_QUAD_FACES = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)


# --------------------------------------------------------------------------
# Primitives
# --------------------------------------------------------------------------
def quads(p0: np.ndarray, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """N quads with corners p0, p0+u, p0+u+v, p0+v; front side along u x v."""
    p0, u, v = (np.asarray(a, dtype=np.float64) for a in (p0, u, v))
    n = max(len(a) if a.ndim == 2 else 1 for a in (p0, u, v))
    # corners written in place, each (n, 3) or (3,) broadcast: the same sums as stacking broadcast
    # copies (a world build makes ~7,000 of these, most of a few quads, where numpy's calls are the cost)
    verts = np.empty((n, 4, 3))
    verts[:, 0] = p0
    verts[:, 1] = p0
    verts[:, 1] += u
    np.add(verts[:, 1], v, out=verts[:, 2])
    verts[:, 3] = p0
    verts[:, 3] += v
    faces = (_QUAD_FACES[None] + 4 * np.arange(n)[:, None, None]).reshape(-1, 3)
    return verts.reshape(-1, 3), faces


def grid(p0, u, v, nu: int, nv: int) -> tuple[np.ndarray, np.ndarray]:
    """A planar quad subdivided into nu x nv cells (shared vertices)."""
    nu, nv = max(1, int(nu)), max(1, int(nv))
    a = np.linspace(0.0, 1.0, nu + 1)
    b = np.linspace(0.0, 1.0, nv + 1)
    aa, bb = np.meshgrid(a, b, indexing="ij")
    verts = (np.asarray(p0, float)[None] + aa.reshape(-1, 1) * np.asarray(u, float)[None]
             + bb.reshape(-1, 1) * np.asarray(v, float)[None])
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    v00 = (i * (nv + 1) + j).ravel()
    v10, v01 = v00 + nv + 1, v00 + 1
    v11 = v10 + 1
    faces = np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)])
    return verts, faces


def ground_rect(x0, y0, x1, y1, z, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Upward-facing subdivided rectangle."""
    nu = int(np.ceil(abs(x1 - x0) / cell))
    nv = int(np.ceil(abs(y1 - y0) / cell))
    return grid((x0, y0, z), (x1 - x0, 0, 0), (0, y1 - y0, 0), nu, nv)


def boxes(centers, sizes, yaws=0.0, bottom: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Oriented boxes; ``centers`` at the box's base centre (z = bottom)."""
    c = np.atleast_2d(np.asarray(centers, dtype=np.float64))
    s = np.atleast_2d(np.asarray(sizes, dtype=np.float64))
    n = max(len(c), len(s))
    c, s = np.broadcast_to(c, (n, 3)), np.broadcast_to(s, (n, 3))
    yaw = np.broadcast_to(np.asarray(yaws, dtype=np.float64), (n,))
    cs, sn = np.cos(yaw), np.sin(yaw)
    ex = np.stack([cs, sn, np.zeros(n)], 1) * s[:, :1]
    ey = np.stack([-sn, cs, np.zeros(n)], 1) * s[:, 1:2]
    ez = np.zeros((n, 3))
    ez[:, 2] = s[:, 2]
    base = c - 0.5 * ex - 0.5 * ey
    # Explicit six faces, each (p0, u, v) with u x v pointing outwards.
    faces_def = [
        (base + ex, ey, ez),  # +x
        (base + ey, -ey, ez),  # -x
        (base + ex + ey, -ex, ez),  # +y
        (base, ex, ez),  # -y
        (base + ez, ex, ey),  # top
    ]
    if bottom:
        faces_def.append((base + ey, ex, -ey))
    # every side of every box in one ``quads`` call: side by side, box by box, the vertices, faces and
    # floats of a call per side (a world build makes ~1,600 calls of a box or a few)
    p0, u, v = (np.concatenate(side) for side in zip(*faces_def))
    return quads(p0, u, v)


def prism_roofs(centers, sizes, heights, yaws=0.0) -> tuple[np.ndarray, np.ndarray]:
    """Gable roofs: ridge along the local x axis, from z=center[2] up by height."""
    c = np.atleast_2d(np.asarray(centers, dtype=np.float64))
    s = np.atleast_2d(np.asarray(sizes, dtype=np.float64))
    n = len(c)
    h = np.broadcast_to(np.asarray(heights, float), (n,))
    yaw = np.broadcast_to(np.asarray(yaws, float), (n,))
    cs, sn = np.cos(yaw), np.sin(yaw)
    ex = np.stack([cs, sn, np.zeros(n)], 1) * s[:, :1] * 0.5
    ey = np.stack([-sn, cs, np.zeros(n)], 1) * s[:, 1:2] * 0.5
    up = np.zeros((n, 3))
    up[:, 2] = h
    a0, a1 = c - ex - ey, c + ex - ey  # front eave
    b0, b1 = c - ex + ey, c + ex + ey  # back eave
    r0, r1 = c - ex + up, c + ex + up  # ridge
    verts = np.stack([a0, a1, r1, r0, b1, b0, r0, r1, a0, r0, b0, a1, b1, r1], 1)
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7], [8, 9, 10], [11, 12, 13]])
    faces = (faces[None] + 14 * np.arange(n)[:, None, None]).reshape(-1, 3)
    return verts.reshape(-1, 3), faces


def _rims(bases, heights, radii, sides: int):
    """Bases (N, 3), heights (N,) and the closed rim circle (N, S+1, 3) around each base."""
    b = np.atleast_2d(np.asarray(bases, dtype=np.float64))
    n = len(b)
    h = np.broadcast_to(np.asarray(heights, float), (n,))
    r = np.broadcast_to(np.asarray(radii, float), (n,))
    ang = np.linspace(0, 2 * np.pi, sides + 1)
    ring = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], 1)  # (S+1, 3)
    return b, h, b[:, None] + r[:, None, None] * ring[None]


def cylinders(bases, heights, radii, sides: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Vertical open cylinders (no caps) standing on ``bases``."""
    b, h, bottom = _rims(bases, heights, radii, sides)
    n = len(b)
    top = bottom.copy()
    top[..., 2] += h[:, None]
    verts = np.concatenate([bottom, top], axis=1).reshape(-1, 3)
    k = np.arange(sides)
    m = sides + 1
    f = np.concatenate([np.stack([k, k + 1, m + k + 1], 1), np.stack([k, m + k + 1, m + k], 1)])
    faces = (f[None] + 2 * m * np.arange(n)[:, None, None]).reshape(-1, 3)
    return verts, faces


def cones(bases, heights, radii, sides: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Vertical cones (no base cap) standing on ``bases``: conifer tiers, silo tops."""
    b, h, rim = _rims(bases, heights, radii, sides)
    n = len(b)
    apex = b + np.stack([np.zeros(n), np.zeros(n), h], 1)
    verts = np.concatenate([rim, apex[:, None]], axis=1).reshape(-1, 3)
    k = np.arange(sides)
    f = np.stack([k, k + 1, np.full(sides, sides + 1)], 1)
    faces = (f[None] + (sides + 2) * np.arange(n)[:, None, None]).reshape(-1, 3)
    return verts, faces


def _icosphere() -> tuple[np.ndarray, np.ndarray]:
    ico = trimesh.creation.icosphere(subdivisions=1)
    return np.asarray(ico.vertices), np.asarray(ico.faces, dtype=np.int64)


_ICO_V, _ICO_F = _icosphere()


def blobs(centers, radii, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Lumpy ellipsoids (tree canopies, bushes); radii (N, 3)."""
    c = np.atleast_2d(np.asarray(centers, dtype=np.float64))
    r = np.atleast_2d(np.asarray(radii, dtype=np.float64))
    n = len(c)
    v = _ICO_V[None] * r[:, None, :] + c[:, None, :]
    bump = 0.75 + 0.5 * value_noise(v.reshape(-1, 3), 1.6, seed).reshape(n, -1, 1)
    v = c[:, None, :] + (v - c[:, None, :]) * bump
    faces = (_ICO_F[None] + len(_ICO_V) * np.arange(n)[:, None, None]).reshape(-1, 3)
    return v.reshape(-1, 3), faces


def ribbon(points_xy: np.ndarray, width_left: float, width_right: float, z: float,
           n_across: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Upward strip along a 2D polyline, from ``width_right`` right to ``width_left`` left."""
    p = np.asarray(points_xy, dtype=np.float64)[:, :2]
    t = np.gradient(p, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    nrm = np.stack([-t[:, 1], t[:, 0]], 1)  # left normal
    a = np.linspace(-width_right, width_left, n_across + 1)
    xy = p[:, None, :] + a[None, :, None] * nrm[:, None, :]
    verts = np.concatenate([xy, np.full(xy.shape[:2] + (1,), z)], axis=2).reshape(-1, 3)
    k, m = len(p), n_across + 1
    i, j = np.meshgrid(np.arange(k - 1), np.arange(n_across), indexing="ij")
    v00 = (i * m + j).ravel()
    v01, v10 = v00 + 1, v00 + m
    v11 = v10 + 1
    faces = np.concatenate([np.stack([v00, v01, v11], 1), np.stack([v00, v11, v10], 1)])
    return verts, orient_up(verts, faces)


def orient_up(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Flip faces whose normal points down."""
    tri = verts[faces]
    nz = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])[:, 2]
    out = faces.copy()
    out[nz < 0] = out[nz < 0][:, [0, 2, 1]]
    return out


def _concat(parts) -> tuple[np.ndarray, np.ndarray]:
    verts, faces, off = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces.append(f + off)
        off += len(v)
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.concatenate(verts), np.concatenate(faces)


def transform(verts: np.ndarray, position, yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    return verts @ rot.T + np.asarray(position, float)


# --------------------------------------------------------------------------
# Procedural colour
# --------------------------------------------------------------------------
def _seed_term(seed: int) -> int:
    return seed * 2654435761 % 2**31


def _hash01(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray, seed) -> np.ndarray:
    """``seed``: an integer, or (several seeds at once) an int64 array of their ``_seed_term``s."""
    term = seed if isinstance(seed, np.ndarray) else _seed_term(seed)
    h = (ix * 73856093) ^ (iy * 19349663) ^ (iz * 83492791) ^ term
    h = (h ^ (h >> 13)) * 1274126177
    h = h ^ (h >> 16)
    return (h & 0xFFFF).astype(np.float64) / 65535.0


def _noise(p: np.ndarray, seed) -> np.ndarray:
    """Value noise at ``p`` (N, 3) in noise cells; ``seed`` as ``_hash01`` takes it."""
    i0 = np.floor(p).astype(np.int64)
    f = p - i0
    f = f * f * (3 - 2 * f)
    # the eight corners' hashes in one pass (integer arithmetic: the same values one by one gave)
    corner = i0[None, :, :] + _CORNERS[:, None, :]  # (8, N, 3)
    hashes = _hash01(corner[..., 0], corner[..., 1], corner[..., 2], seed)
    weights = np.stack(((1 - f).T, f.T))  # [side, axis]: (2, 3, N)
    terms = weights[_CORNERS[:, 0], 0] * weights[_CORNERS[:, 1], 1] * weights[_CORNERS[:, 2], 2] * hashes
    # added up corner by corner in order (accumulate is sequential), so the same floats as the loop gave
    return np.add.accumulate(terms, axis=0)[-1] if len(p) else np.zeros(0)


def value_noise(points: np.ndarray, scale: float, seed: int) -> np.ndarray:
    """Smooth deterministic noise in [0, 1] at ``points`` (N, 3); ``scale`` in metres."""
    return _noise(np.asarray(points, dtype=np.float64) / scale, seed)


_CORNERS = np.array([(dx, dy, dz) for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)], np.int64)


def noisy_colors(verts: np.ndarray, base, amount: float = 0.15, scale: float = 3.0,
                 seed: int = 0, fine: float = 0.05) -> np.ndarray:
    """uint8 RGBA colours: ``base`` modulated by two octaves of value noise.

    The same floats as ``value_noise`` at ``scale`` and ``seed``, then at ``scale * 0.23`` and ``seed + 7``,
    both octaves in one pass over the points stacked twice; one piece made as a batch makes many
    (:class:`NoiseColors`)."""
    return _made_together([NoiseColors(verts, base, amount, scale, seed, fine)])[0]


class NoiseColors:
    """:func:`noisy_colors` of a piece, asked for when the piece is added and made when its batch is
    merged (:meth:`MeshBatch.parts`), together with every other piece's in a few numpy passes: a town
    adds some 3,000 pieces of a few dozen vertices each, where numpy's per-call cost was most of the
    time (~0.25 of T03's ~0.9 CPU-s world build). Each point's noise is computed on its own, so made
    together or one by one the colours are the same bytes."""

    __slots__ = ("verts", "base", "amount", "scale", "seed", "fine")

    def __init__(self, verts: np.ndarray, base, amount: float = 0.15, scale: float = 3.0, seed: int = 0,
                 fine: float = 0.05) -> None:
        self.verts = np.array(verts, dtype=np.float64)  # a copy: the colours are of the points as added
        self.base = np.array(base, dtype=np.float64)
        self.amount, self.scale, self.seed, self.fine = amount, scale, seed, fine

    def __len__(self) -> int:
        return len(self.verts)

    def made(self) -> np.ndarray:
        return _made_together([self])[0]

    def __getitem__(self, index) -> NoiseColors:
        """The colours of some of the points (an index into them), still to be made: each point's are its own."""
        return NoiseColors(self.verts[index], self.base, self.amount, self.scale, self.seed, self.fine)


NOISE_POINTS_PER_PASS = 1 << 15  # points per batched noise pass (its temporaries: ~400 bytes a point)


def made_colors(asked: list[NoiseColors]) -> list[np.ndarray]:
    """The colours of ``asked``, in order: as :meth:`NoiseColors.made` gives each, a few passes for all."""
    out: list[np.ndarray] = []
    start = 0
    while start < len(asked):
        stop, points = start, 0
        while stop < len(asked) and (points == 0 or points + len(asked[stop]) <= NOISE_POINTS_PER_PASS):
            points += len(asked[stop])
            stop += 1
        out.extend(_made_together(asked[start:stop]))
        start = stop
    return out


def _made_together(asked: list[NoiseColors]) -> list[np.ndarray]:
    """:func:`noisy_colors` of several pieces in one pass: per point the same floats, operation by operation."""
    counts = [len(a) for a in asked]
    n = sum(counts)
    points = np.concatenate([a.verts / a.scale for a in asked] + [a.verts / (a.scale * 0.23) for a in asked])
    terms = np.repeat(np.array([_seed_term(a.seed) for a in asked] + [_seed_term(a.seed + 7) for a in asked],
                               np.int64), counts + counts)
    noise = _noise(points, terms)
    n1, n2 = noise[:n] - 0.5, noise[n:] - 0.5
    amount = np.repeat(np.array([2 * a.amount for a in asked], np.float64), counts)
    detail = np.repeat(np.array([2 * a.fine for a in asked], np.float64), counts)
    gain = 1.0 + amount * n1 + detail * n2
    base = np.repeat(np.array([a.base[:3] for a in asked], np.float64).reshape(-1, 3), counts, axis=0)
    rgb = np.clip(base * gain[:, None], 0, 255)
    out = np.empty((n, 4), dtype=np.uint8)
    out[:, :3] = rgb.astype(np.uint8)
    out[:, 3] = 255
    return np.split(out, np.cumsum(counts)[:-1])


def flat_colors(n: int, base) -> np.ndarray:
    out = np.empty((n, 4), dtype=np.uint8)
    out[:, :3] = np.asarray(base, dtype=np.uint8)[:3]
    out[:, 3] = 255
    return out


# --------------------------------------------------------------------------
# Batching into Parts
# --------------------------------------------------------------------------
class MeshBatch:
    """Collects geometry per (tile, class_id, material, texture) and merges it."""

    def __init__(self, tile_m: float = TILE_M) -> None:
        self.tile_m = tile_m
        self._chunks: dict[tuple, list] = defaultdict(list)

    def add(self, class_id: int, material: str, verts: np.ndarray, faces: np.ndarray,
            colors: np.ndarray, anchor=None, texture: str = "") -> None:
        """Add one piece; it goes to the tile of ``anchor`` (default: its centre)."""
        if len(faces) == 0:
            return
        if anchor is None:
            anchor = 0.5 * (verts.min(axis=0) + verts.max(axis=0))
        tile = (int(np.floor(anchor[0] / self.tile_m)), int(np.floor(anchor[1] / self.tile_m)))
        self._chunks[(tile, class_id, material, texture)].append((verts, faces, colors))

    def add_tiled(self, class_id: int, material: str, verts, faces, colors, texture: str = "") -> None:
        """Add a piece that may span tiles: each face goes to its centroid's tile."""
        cen = verts[faces].mean(axis=1)
        tiles = np.floor(cen[:, :2] / self.tile_m).astype(np.int64)
        keys, inverse = np.unique(tiles, axis=0, return_inverse=True)
        for k, key in enumerate(keys):
            sel = faces[inverse.ravel() == k]
            used, remap = np.unique(sel, return_inverse=True)
            self._chunks[((int(key[0]), int(key[1])), class_id, material, texture)].append(
                (verts[used], remap.reshape(-1, 3), colors[used]))

    def parts(self) -> tuple[Part, ...]:
        asked = [c for chunks in self._chunks.values() for _, _, c in chunks if isinstance(c, NoiseColors)]
        made = dict(zip(map(id, asked), made_colors(asked)))
        for chunks in self._chunks.values():
            chunks[:] = [(v, f, made.get(id(c), c)) for v, f, c in chunks]
        out = []
        for key in sorted(self._chunks):
            _, class_id, material, texture = key
            chunks = self._chunks[key]
            verts, faces = _concat([(v, f) for v, f, _ in chunks])
            colors = np.concatenate([c for _, _, c in chunks])
            mesh = trimesh.Trimesh(vertices=verts, faces=faces, vertex_colors=colors, process=False)
            out.append(Part(class_id=class_id, mesh=mesh, material=material, texture=texture))
        return tuple(out)
