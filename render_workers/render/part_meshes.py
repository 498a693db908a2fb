"""Parts to pyrender meshes: material looks, flat-shaded triangle soups grouped
per (tile, class, material, texture) for static geometry and per (class,
material) for actors, with box-mapped texture coordinates where a part has a
texture."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from domains.catalog import lookup
from render_workers.render import pyrender_setup as compat
from render_workers.worlds.scene import MATERIALS, Part
from render_workers.worlds.textures import box_uv, texture_kind


# --------------------------------------------------------------------------
# Materials
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class Look:
    """pyrender MetallicRoughnessMaterial settings for one ``Part.material``."""

    metallic: float
    roughness: float
    emissive: float = 0.0  # emissive factor; vertex colours tint it


LOOKS: dict[str, Look] = {
    "matte": Look(0.0, 0.95),
    "glossy": Look(0.05, 0.45),
    "metal": Look(0.6, 0.35),
    "glass": Look(0.3, 0.12),
    "emissive": Look(0.0, 0.9, emissive=1.5),
    "road": Look(0.0, 0.85),
    "water": Look(0.2, 0.08),
}
if set(LOOKS) != set(MATERIALS):
    raise RuntimeError(f"material looks {sorted(LOOKS)} do not match scene.MATERIALS {sorted(MATERIALS)}")


def look(material: str) -> Look:
    return lookup(LOOKS, material, "material")


def pyrender_material(material: str, texture=None):
    """A pyrender ``MetallicRoughnessMaterial`` for a ``Part.material`` key (and a pyrender Texture)."""
    pr = compat.import_pyrender()
    lk = look(material)
    return pr.MetallicRoughnessMaterial(
        baseColorTexture=texture,
        baseColorFactor=[1.0, 1.0, 1.0, 1.0],
        metallicFactor=lk.metallic,
        roughnessFactor=lk.roughness,
        emissiveFactor=[lk.emissive] * 3,
        alphaMode="OPAQUE",
        doubleSided=True,
    )


# --------------------------------------------------------------------------
# Geometry -> flat-shaded triangle soups
# --------------------------------------------------------------------------
@dataclass
class _Soup:
    """Unindexed triangles: positions, normals, linear RGBA colours and texture coordinates, float32."""

    positions: list = field(default_factory=list)
    normals: list = field(default_factory=list)
    colors: list = field(default_factory=list)
    uvs: list = field(default_factory=list)  # empty for untextured soups

    def add(self, positions: np.ndarray, normals: np.ndarray, colors: np.ndarray, uvs=None) -> None:
        self.positions.append(positions)
        self.normals.append(normals)
        self.colors.append(colors)
        if uvs is not None:
            self.uvs.append(uvs)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        return (
            np.concatenate(self.positions).astype(np.float32),
            np.concatenate(self.normals).astype(np.float32),
            np.concatenate(self.colors).astype(np.float32),
            np.concatenate(self.uvs).astype(np.float32) if self.uvs else None,
        )


_SRGB_TO_LINEAR = (np.arange(256, dtype=np.float64) / 255.0) ** 2.2


def _corner_colors(mesh) -> np.ndarray:
    """(F, 3, 4) linear RGBA per triangle corner from a trimesh's vertex/face colours."""
    faces = mesh.faces
    kind = mesh.visual.kind if mesh.visual.defined else None
    if kind == "vertex":
        rgba = np.asarray(mesh.visual.vertex_colors)[faces]
    elif kind == "face":
        rgba = np.repeat(np.asarray(mesh.visual.face_colors)[:, None, :], 3, axis=1)
    else:
        rgba = np.full((len(faces), 3, 4), 128, dtype=np.uint8)
    out = _SRGB_TO_LINEAR[rgba]
    out[..., 3] = 1.0  # opaque: alpha is used for sky coverage
    return out


def _triangles(mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    tri = np.asarray(mesh.vertices, dtype=np.float64)[mesh.faces]  # (F, 3, 3)
    normals = np.repeat(np.asarray(mesh.face_normals)[:, None, :], 3, axis=1)
    return tri, normals, _corner_colors(mesh)


def _sphere(positions: np.ndarray) -> tuple[np.ndarray, float]:
    lo, hi = positions.min(axis=0), positions.max(axis=0)
    centre = (lo + hi) / 2
    return centre.astype(np.float64), float(np.linalg.norm(hi - lo) / 2)


def _part_triangles(parts: tuple[Part, ...]):
    """(part, (triangles, normals, colours)) for every non-empty part; checks its material."""
    for part in parts:
        if len(part.mesh.faces):
            look(part.material)
            yield part, _triangles(part.mesh)


def static_groups(parts: tuple[Part, ...], tile_m: float) -> dict[tuple, _Soup]:
    """Static triangles grouped by (tile x, tile y, class id, material, texture), by face centroid;
    textured ones get box-mapped texture coordinates from their world positions."""
    groups: dict[tuple, _Soup] = {}
    for part, (tri, normals, colors) in _part_triangles(parts):
        uv = box_uv(tri, normals[:, 0], texture_kind(part.texture).size_m) if part.texture else None
        tiles = np.floor(tri.mean(axis=1)[:, :2] / tile_m).astype(np.int64)
        if (tiles == tiles[0]).all():  # the whole part in one tile (most are: the world is batched by tile)
            keys, inverse = tiles[:1], None
        else:
            keys, inverse = np.unique(tiles, axis=0, return_inverse=True)
            inverse = inverse.ravel()
        for k, (tx, ty) in enumerate(keys):
            sel = slice(None) if inverse is None else inverse == k
            soup = groups.setdefault((int(tx), int(ty), part.class_id, part.material, part.texture), _Soup())
            soup.add(tri[sel].reshape(-1, 3), normals[sel].reshape(-1, 3), colors[sel].reshape(-1, 4),
                     None if uv is None else uv[sel].reshape(-1, 2))
    return groups


def part_groups(parts: tuple[Part, ...]) -> dict[tuple, _Soup]:
    """An actor's triangles grouped by (class id, material)."""
    groups: dict[tuple, _Soup] = {}
    for part, (tri, normals, colors) in _part_triangles(parts):
        groups.setdefault((part.class_id, part.material), _Soup()).add(
            tri.reshape(-1, 3), normals.reshape(-1, 3), colors.reshape(-1, 4)
        )
    return groups


def _pyrender_mesh(soup: _Soup, material: str, texture=None):
    pr = compat.import_pyrender()
    positions, normals, colors, uvs = soup.arrays()
    primitive = pr.Primitive(
        positions=positions, normals=normals, color_0=colors, texcoord_0=uvs if texture is not None else None,
        material=pyrender_material(material, texture), mode=4
    )
    return pr.Mesh(primitives=[primitive]), positions
