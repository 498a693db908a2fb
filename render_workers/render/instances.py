"""Instances: which geometry is an object, its per-episode id, and its boxes per frame.

Objects are the actors' parts of the instance classes (``Label.instances``:
one object per actor and class, so a cyclist is a rider and a bicycle) and
the static traffic lights and signs, which the world merges per class: they
are split back into objects here (boxes that touch within ``TOUCH_M`` form one
object, e.g. a signal head and its lamps). All other static geometry stays in
merged tiles and has instance id 0.

Ids, per episode: ``HOOD_ID`` for the ego hood, then the static objects in a
fixed order (by class and position), then the actors' objects in scene order.
They are stable over the episode's frames.

:func:`frame_objects` turns a frame's instance ids into the ``objects`` sidecar
(``outputs.objects``): tight 2D boxes, visible pixels, occlusion against the
object's own silhouette (rasterised from its triangles), truncation of its
projected 3D box, and the 3D box in OpenCV camera coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from domains.catalog import LABELS
from outputs.objects import HOOD_ID, INSTANCE_CLASS_IDS, box_corners, label_counts, object_table
from render_workers.worlds.scene import EpisodeScene, Part

MAX_ID = 2**16 - 1
TOUCH_M = 0.05  # static boxes closer than this belong to one object
NEAR_M = 0.1  # silhouettes are clipped at this depth
CV_FROM_GL = np.diag([1.0, -1.0, -1.0])  # camera axes: OpenGL (x right, y up, -z ahead) -> OpenCV


@dataclass(frozen=True, eq=False)
class Instance:
    """One object of an episode; geometry in its actor's frame (static: the world)."""

    id: int
    class_id: int
    actor: int  # index in EpisodeScene.actors; -1 for static objects
    centre: np.ndarray  # (3,) box centre
    size: np.ndarray  # (3,) length, width, height along the box axes
    yaw: float  # box heading about +z (radians)
    triangles: np.ndarray  # (T, 3, 3) for the silhouette


def _components(tri: np.ndarray) -> np.ndarray:
    """Component label per triangle: triangles sharing a corner position (to 1 mm) are connected."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    _, vid = np.unique(np.round(tri.reshape(-1, 3) * 1000).astype(np.int64), axis=0, return_inverse=True)
    vid = vid.reshape(-1, 3)
    n = int(vid.max()) + 1
    rows = np.concatenate([vid[:, 0], vid[:, 0]])
    cols = np.concatenate([vid[:, 1], vid[:, 2]])
    _, labels = connected_components(coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)), directed=False)
    return labels[vid[:, 0]]


def _touching(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Group label per box: boxes whose bounds come within TOUCH_M are grouped (transitively)."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    near = ((lo[:, None, :] - TOUCH_M <= hi[None, :, :]) & (lo[None, :, :] - TOUCH_M <= hi[:, None, :])).all(axis=2)
    return connected_components(csr_matrix(near), directed=False)[1]


def split_static(parts: tuple[Part, ...]) -> tuple[tuple[Part, ...], list[tuple[Part, ...]]]:
    """The static parts without the instance classes, and those split into objects
    (each a tuple of Parts, one per material), in a fixed order."""
    import trimesh

    rest, pieces = [], []  # pieces: (class id, material, texture, triangles)
    for part in parts:
        if part.class_id not in INSTANCE_CLASS_IDS or not len(part.mesh.faces):
            rest.append(part)
            continue
        tri = np.asarray(part.mesh.vertices, np.float64)[part.mesh.faces]
        colors = np.asarray(part.mesh.visual.face_colors) if part.mesh.visual.defined else None
        labels = _components(tri)
        for k in range(int(labels.max()) + 1):
            sel = labels == k
            pieces.append((part.class_id, part.material, part.texture, tri[sel], None if colors is None else colors[sel]))
    objects: list[tuple[Part, ...]] = []
    for cls in sorted({p[0] for p in pieces}):
        mine = [p for p in pieces if p[0] == cls]
        lo = np.array([p[3].reshape(-1, 3).min(axis=0) for p in mine])
        hi = np.array([p[3].reshape(-1, 3).max(axis=0) for p in mine])
        group = _touching(lo, hi)
        order = sorted(range(int(group.max()) + 1), key=lambda g: tuple(np.round(lo[group == g].min(axis=0), 3)))
        for g in order:
            members = [mine[i] for i in np.flatnonzero(group == g)]
            obj = []
            for material, texture in sorted({(m[1], m[2]) for m in members}):
                same = [m for m in members if (m[1], m[2]) == (material, texture)]
                tri = np.concatenate([m[3] for m in same])
                mesh = trimesh.Trimesh(tri.reshape(-1, 3), np.arange(len(tri) * 3).reshape(-1, 3), process=False)
                if same[0][4] is not None:
                    mesh.visual.face_colors = np.concatenate([m[4] for m in same])
                obj.append(Part(cls, mesh, material, texture))
            objects.append(tuple(obj))
    return tuple(rest), objects


def _box(tri: np.ndarray, oriented: bool) -> tuple[np.ndarray, np.ndarray, float]:
    """Centre, size and yaw of a box around triangles: axis-aligned in their frame,
    or (``oriented``) the smallest rectangle over x, y."""
    pts = tri.reshape(-1, 3)
    z0, z1 = pts[:, 2].min(), pts[:, 2].max()
    if not oriented:
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        return (lo + hi) / 2, hi - lo, 0.0
    import cv2

    (x, y), (w, h), angle = cv2.minAreaRect(pts[:, :2].astype(np.float32))
    return np.array([x, y, (z0 + z1) / 2]), np.array([w, h, z1 - z0]), float(np.radians(angle))


def episode_instances(scene: EpisodeScene, static_objects: list[tuple[Part, ...]]) -> list[Instance]:
    """Every object of an episode with its id (HOOD_ID is taken by the hood)."""
    out: list[Instance] = []
    next_id = HOOD_ID + 1
    for parts in static_objects:
        tri = np.concatenate([np.asarray(p.mesh.vertices)[p.mesh.faces] for p in parts])
        centre, size, yaw = _box(tri, oriented=True)
        out.append(Instance(next_id, parts[0].class_id, -1, centre, size, yaw, tri))
        next_id += 1
    for index, actor in enumerate(scene.actors):
        for cls in sorted({p.class_id for p in actor.parts if p.class_id in INSTANCE_CLASS_IDS}):
            tri = np.concatenate([np.asarray(p.mesh.vertices)[p.mesh.faces] for p in actor.parts
                                  if p.class_id == cls and len(p.mesh.faces)])
            centre, size, yaw = _box(tri, oriented=False)
            out.append(Instance(next_id, cls, index, centre, size, yaw, tri))
            next_id += 1
    if next_id - 1 > MAX_ID:
        raise ValueError(f"{next_id - 1} instance ids do not fit a 16-bit PNG")
    return out


def instance_classes(instances: list[Instance]) -> np.ndarray:
    """Class id per instance id (-1 for 0, the hood and unused ids)."""
    table = np.full(max([HOOD_ID] + [i.id for i in instances]) + 1, -1, np.int64)
    for inst in instances:
        table[inst.id] = inst.class_id
    return table


def _clip_near(poly: np.ndarray) -> np.ndarray:
    """A polygon (OpenCV camera frame) clipped to z >= NEAR_M (Sutherland-Hodgman, one plane)."""
    out = []
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):
        ina, inb = a[2] >= NEAR_M, b[2] >= NEAR_M
        if ina:
            out.append(a)
        if ina != inb:
            out.append(a + (b - a) * (NEAR_M - a[2]) / (b[2] - a[2]))
    return np.array(out)


def _project(points: np.ndarray, focal: float, cx: float, cy: float) -> np.ndarray:
    """(..., 3) camera points -> (..., 2) pixels."""
    return np.stack([cx + focal * points[..., 0] / points[..., 2], cy + focal * points[..., 1] / points[..., 2]], axis=-1)


def _silhouette(tri_cam: np.ndarray, window: tuple[slice, slice], shape: tuple[int, int], focal: float,
                cx: float, cy: float) -> np.ndarray:
    """Pixels covered by triangles (camera frame) if nothing were in front of them,
    in the image window that holds their projection (and ``window``, the visible box)."""
    import cv2

    h, w = shape
    front = tri_cam[:, :, 2] >= NEAR_M
    whole = front.all(axis=1)
    limit = 8.0 * max(h, w)

    def to_pixels(points: np.ndarray) -> np.ndarray:  # pixel centres at +0.5
        return np.clip(_project(points, focal, cx, cy) - 0.5, -limit, limit)

    # triangles wholly in front, projected at once; then those the near plane cuts, one by one
    whole_px = to_pixels(tri_cam[whole])  # (n, 3, 2)
    cut_px = [to_pixels(p) for p in (_clip_near(tri_cam[i]) for i in np.flatnonzero(front.any(axis=1) & ~whole))
              if len(p) >= 3]
    ys, xs = window
    x0, y0, x1, y1 = xs.start, ys.start, xs.stop, ys.stop
    if len(whole_px) or cut_px:
        every = np.concatenate([whole_px.reshape(-1, 2), *cut_px])
        lo, hi = every.min(axis=0), every.max(axis=0)
        x0, y0 = min(x0, max(0, int(np.floor(lo[0])))), min(y0, max(0, int(np.floor(lo[1]))))
        x1, y1 = max(x1, min(w, int(np.ceil(hi[0])) + 1)), max(y1, min(h, int(np.ceil(hi[1])) + 1))
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    shift = 4
    origin = np.array([x0, y0], np.float64)
    def to_fixed(px: np.ndarray) -> np.ndarray:  # pixels -> the window's fixed-point vertices
        return np.rint((px - origin) * (1 << shift)).astype(np.int32)

    # the whole triangles converted at once (the same values one by one gave), the cut polygons each
    for px in [*to_fixed(whole_px), *map(to_fixed, cut_px)]:
        cv2.fillConvexPoly(mask, px, 1, lineType=cv2.LINE_8, shift=shift)
    return (slice(y0, y1), slice(x0, x1)), mask.astype(bool)


def frame_objects(instance: np.ndarray, instances: list[Instance], poses: list[np.ndarray],
                 world_from_camera: np.ndarray, focal: float, pixels: np.ndarray | None = None):
    """The frame's ``objects`` sidecar: one row per instance id visible in ``instance``.

    ``poses[a]`` is actor a's world-from-actor pose at the frame's time; ``pixels``: the frame's
    pixels per instance id (``label_counts`` of ``instance``), where the caller has it already."""
    from scipy import ndimage

    h, w = instance.shape
    cx, cy = w / 2.0, h / 2.0
    cam_from_world = np.linalg.inv(world_from_camera)
    rot = CV_FROM_GL @ cam_from_world[:3, :3]
    by_id = {inst.id: inst for inst in instances}
    if pixels is None:
        pixels = label_counts(instance)
    boxes = ndimage.find_objects(instance)  # the uint16 ids as they are (an int32 copy gave the same boxes)
    rows = []
    for iid in np.flatnonzero(pixels):
        inst = by_id.get(int(iid))
        if inst is None:  # 0 and the hood
            continue
        ys, xs = boxes[iid - 1]
        world = np.eye(4) if inst.actor < 0 else poses[inst.actor]
        to_cam_r, to_cam_t = rot @ world[:3, :3], rot @ world[:3, 3] + CV_FROM_GL @ cam_from_world[:3, 3]
        centre = to_cam_r @ inst.centre + to_cam_t
        forward = to_cam_r @ np.array([np.cos(inst.yaw), np.sin(inst.yaw), 0.0])
        tri_cam = inst.triangles @ to_cam_r.T + to_cam_t
        crop, sil = _silhouette(tri_cam, boxes[iid - 1], (h, w), focal, cx, cy)
        amodal = int(np.count_nonzero(sil | (instance[crop] == iid)))
        rows.append({
            "instance_id": int(iid), "class_id": inst.class_id, "class_name": LABELS[inst.class_id].name,
            "x0": xs.start, "y0": ys.start, "x1": xs.stop, "y1": ys.stop, "pixels": int(pixels[iid]),
            "occlusion": 1.0 - int(pixels[iid]) / amodal,
            "truncation": _truncation(centre, inst.size, forward, focal, cx, cy, w, h),
            "cx": centre[0], "cy": centre[1], "cz": centre[2],
            "length": inst.size[0], "width": inst.size[1], "height": inst.size[2],
            "yaw": float(np.arctan2(-forward[2], forward[0])),
        })
    return object_table(rows)


def _truncation(centre, size, forward, focal, cx, cy, w, h) -> float:
    """Share of the projected 3D box's 2D extent outside the image."""
    corners = box_corners(centre, size, float(np.arctan2(-forward[2], forward[0])))
    edges = [(i, j) for i in range(8) for j in range(i + 1, 8) if bin(i ^ j).count("1") == 1]
    pts = [corners[i] for i in range(8) if corners[i][2] >= NEAR_M]
    for i, j in edges:  # where the box's edges cross the near plane
        a, b = corners[i], corners[j]
        if (a[2] >= NEAR_M) != (b[2] >= NEAR_M):
            pts.append(a + (b - a) * (NEAR_M - a[2]) / (b[2] - a[2]))
    if not pts:
        return 1.0
    px = _project(np.array(pts), focal, cx, cy)
    (x0, y0), (x1, y1) = px.min(axis=0), px.max(axis=0)
    area = max((x1 - x0) * (y1 - y0), 1e-9)
    inside = max(0.0, min(x1, w) - max(x0, 0.0)) * max(0.0, min(y1, h) - max(y0, 0.0))
    return float(np.clip(1.0 - inside / area, 0.0, 1.0))
