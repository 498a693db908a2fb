"""Procedural textures made with numpy: asphalt with cracks, brick and paving
courses, plaster, concrete panels, glass mullions, grass, crops, soil, gravel,
tall crops' stalks.

A texture is a tileable ``TEXTURE_PX`` square, grey (the same value in R, G and
B): the renderer multiplies a part's vertex colours (the surface's colour and
its large-scale variation) by it, so one texture serves every colour of its
kind. ``TEXTURES`` gives each its size on the ground or wall in metres; the
renderer maps it box-wise from world positions (ground: x, y; walls: the
horizontal axis and z), so meshes need no UVs of their own.

``town_textures(style, seed)`` makes the set a town uses, seeded per town and
cached: asphalt cracks follow ``Style.asphalt_wear``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Callable

import numpy as np

from domains.catalog import lookup
from render_workers.worlds.styles import SURFACES, TEXTURE_NAMES, Style

TEXTURE_PX = 256
TEXTURE_MEAN = 0.8  # mean of every texture: surfaces under one are drawn 1 / 0.8 brighter


def _smooth_noise(rng, px: int, cells: int) -> np.ndarray:
    """Tileable value noise in [0, 1] with ``cells`` cells across."""
    g = rng.random((cells, cells))
    t = np.arange(px) * cells / px
    i0 = np.floor(t).astype(int)
    f = t - i0
    f = f * f * (3 - 2 * f)
    i1 = (i0 + 1) % cells
    rows = g[i0] * (1 - f)[:, None] + g[i1] * f[:, None]
    return rows[:, i0] * (1 - f)[None] + rows[:, i1] * f[None]


def _octaves(rng, px: int, cells=(4, 8, 16, 32, 64), gains=(0.35, 0.25, 0.18, 0.12, 0.1)) -> np.ndarray:
    out = sum(g * _smooth_noise(rng, px, c) for c, g in zip(cells, gains))
    return (out - out.min()) / max(np.ptp(out), 1e-9)


def _cracks(rng, px: int, n: int) -> np.ndarray:
    """Mask of thin random-walk cracks (tileable by wrapping)."""
    mask = np.zeros((px, px), bool)
    for _ in range(n):
        p = rng.random(2) * px
        ang = rng.random() * 2 * np.pi
        for _ in range(int(rng.integers(40, 160))):
            ang += rng.normal(0, 0.35)
            p = p + 1.5 * np.array([np.cos(ang), np.sin(ang)])
            i, j = int(p[0]) % px, int(p[1]) % px
            mask[i, j] = mask[(i + 1) % px, j] = mask[i, (j + 1) % px] = True
    return mask


def _asphalt(rng, px, wear):
    base = 0.62 + 0.38 * _octaves(rng, px)
    grain = rng.random((px, px))
    base += 0.16 * (grain - 0.5)
    base[grain > 0.98] += 0.2  # light aggregate stones
    base[_cracks(rng, px, int(2 + 16 * wear))] *= 0.4
    return base


def _courses(px, rows: int, bricks: int, mortar: float, jitter, rng, stagger=True):
    """Brick or slab courses: ``rows`` x ``bricks`` units with mortar joints."""
    y = np.arange(px)[:, None] * rows / px
    x = np.arange(px)[None, :] * bricks / px
    row = np.floor(y).astype(int)
    xs = x + (0.5 * (row % 2) if stagger else 0.0)
    col = np.floor(xs).astype(int) % bricks
    shade = 1.0 - jitter * rng.random((rows, bricks))
    out = shade[row % rows, col]
    joint = (np.abs(y - np.round(y)) < mortar * rows / 2) | (np.abs(xs - np.round(xs)) < mortar * bricks / 2)
    return np.where(joint, 1.0, out * 0.72)


def _brick(rng, px, wear):
    return _courses(px, 24, 6, 0.012, 0.18, rng) * (0.9 + 0.1 * _octaves(rng, px))


def _paving(rng, px, wear):
    slabs = _courses(px, 8, 8, 0.02, 0.25, rng, stagger=False)
    return np.where(slabs >= 1.0, 0.55, slabs / 0.72) * (0.8 + 0.2 * _octaves(rng, px))


def _plaster(rng, px, wear):
    return 0.78 + 0.2 * _octaves(rng, px, (2, 4, 8)) + 0.06 * (rng.random((px, px)) - 0.5)


def _concrete(rng, px, wear):
    out = 0.84 + 0.12 * _octaves(rng, px) + 0.05 * (rng.random((px, px)) - 0.5)
    k = np.arange(px)
    seam = (k % (px // 2) < 2)
    out[seam, :] *= 0.75
    out[:, seam] *= 0.75
    return out


def _glass(rng, px, wear):
    y = np.arange(px)[:, None] / px
    out = np.broadcast_to(0.75 + 0.3 * (1 - y), (px, px)).copy()  # sky reflection: lighter at the top of a floor
    k = np.arange(px)
    mull = (k % (px // 4) < 3)
    out[:, mull] = 0.45
    out[k % px < 5, :] = 0.45
    return out


def _grass(rng, px, wear):
    blades = rng.random((px, px))
    return 0.6 + 0.32 * _octaves(rng, px, (4, 8, 16, 32)) + 0.34 * (blades - 0.5)


def _crop(rng, px, wear):
    x = np.arange(px)[None, :] / px
    rows = 0.6 + 0.4 * np.cos(2 * np.pi * 4 * x) ** 2
    return rows * (0.85 + 0.3 * (rng.random((px, px)) - 0.5)) + 0.08 * _octaves(rng, px)


def _soil(rng, px, wear):
    out = 0.65 + 0.3 * _octaves(rng, px, (4, 16, 64))
    out[rng.random((px, px)) > 0.95] *= 0.6  # clods
    return out


def _stalks(rng, px, wear):
    """Tall crops seen side-on: dark gaps between stalks, lighter leaves slanting off them."""
    x = np.arange(px)[None, :] / px
    y = np.arange(px)[:, None] / px
    phase = rng.random(12)[np.floor(x * 12).astype(int) % 12]  # each stalk wobbles its own way
    stalks = np.abs(np.sin(np.pi * (12 * x + 0.15 * np.sin(2 * np.pi * (2 * y + phase)))))
    leaves = _smooth_noise(rng, px, 32) * (0.6 + 0.4 * np.abs(np.sin(2 * np.pi * (9 * y + 6 * x))))
    return 0.45 + 0.4 * stalks ** 0.5 + 0.3 * leaves + 0.1 * (rng.random((px, px)) - 0.5)


def _gravel(rng, px, wear):
    stones = _smooth_noise(rng, px, 64)
    return 0.55 + 0.5 * (stones > 0.5) * stones + 0.15 * (rng.random((px, px)) - 0.5)


@dataclass(frozen=True)
class TextureKind:
    size_m: float  # edge of one tile on the surface
    make: Callable  # (rng, px, wear) -> (px, px) float, ~0.4..1.1


TEXTURES: dict[str, TextureKind] = {
    "asphalt": TextureKind(6.0, _asphalt),
    "brick": TextureKind(1.6, _brick),
    "paving": TextureKind(2.0, _paving),
    "plaster": TextureKind(4.0, _plaster),
    "concrete": TextureKind(3.0, _concrete),
    "glass": TextureKind(3.5, _glass),
    "grass": TextureKind(3.0, _grass),
    "crop": TextureKind(2.4, _crop),
    "soil": TextureKind(3.0, _soil),
    "gravel": TextureKind(1.5, _gravel),
    "stalks": TextureKind(2.0, _stalks),
}
if set(TEXTURES) != set(TEXTURE_NAMES):
    raise RuntimeError(f"textures {sorted(TEXTURES)} do not match catalog.TEXTURE_NAMES {sorted(TEXTURE_NAMES)}")


def texture_kind(name: str) -> TextureKind:
    return lookup(TEXTURES, name, "texture")


@lru_cache(maxsize=16)
def town_textures(style: Style, seed: int, stream: int) -> dict[str, np.ndarray]:
    """The textures of a town (``stream``: ``Town.stream``) as (px, px, 3) uint8 grey images."""
    names = sorted({s.texture for s in SURFACES if s.texture})
    out = {}
    for k, name in enumerate(names):
        rng = np.random.default_rng([seed, stream, k, 7])
        img = np.asarray(texture_kind(name).make(rng, TEXTURE_PX, style.asphalt_wear))
        img = img * (TEXTURE_MEAN / img.mean())  # every texture darkens by the same share on average
        grey = np.clip(img * 255.0, 0, 255).astype(np.uint8)
        out[name] = np.repeat(grey[..., None], 3, axis=2)
    return out


def box_uv(triangles: np.ndarray, normals: np.ndarray, size_m: float) -> np.ndarray:
    """(F, 3, 2) texture coordinates of world triangles (F, 3, 3): ground faces
    map x, y; walls map their horizontal axis and z."""
    n = np.abs(normals)
    up = n[:, 2] >= np.maximum(n[:, 0], n[:, 1])
    wall_x = ~up & (n[:, 0] >= n[:, 1])  # a wall facing +-x runs along y
    u = np.where(up[:, None], triangles[..., 0], np.where(wall_x[:, None], triangles[..., 1], triangles[..., 0]))
    v = np.where(up[:, None], triangles[..., 1], triangles[..., 2])
    return np.stack([u, v], -1) / size_m
