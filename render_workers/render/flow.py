"""Forward optical flow from the renderer's geometry and each object's motion (no estimator).

A pixel of frame t sees a surface point (back-projected from the planar depth
with ``K``). Static geometry stays where it is in the world; a point on an actor
(a vehicle, pedestrian, rider...) moves with that actor, ``pose(t') @
inv(pose(t))``; the ego's hood moves with the camera. Projected into the camera
at t' = t + interval, the point's pixel minus its pixel at t is the flow. It is
invalid where there is no surface (sky), where the point's next position is
behind the camera or outside the image, and (the caller's business) for the
last frame of an episode. Occlusion at t' is not checked.
"""

from __future__ import annotations

import numpy as np

from outputs.geometry import CV_FROM_GL, depth_to_world, project, world_to_camera
from outputs.objects import HOOD_ID


def forward_flow(depth: np.ndarray, instance: np.ndarray, K: np.ndarray, cam_now: np.ndarray,
                 cam_next: np.ndarray, moves: dict[int, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(HxWx2 float32 flow in pixels, HxW bool valid) of frame t to frame t'.

    ``cam_now`` / ``cam_next``: OpenCV cam_to_world at t and t'; ``moves``: instance id -> 4x4
    world motion of that object from t to t' (ids not listed are static; the hood moves with the camera)."""
    h, w = depth.shape
    v, u = np.nonzero(depth < 999.0)
    points = depth_to_world(depth, K, cam_now)  # same pixel order as np.nonzero
    ids = instance[v, u]
    for iid, motion in moves.items():
        sel = ids == iid
        if sel.any():
            points[sel] = points[sel] @ motion[:3, :3].T + motion[:3, 3]
    cam = world_to_camera(points, cam_next)
    hood = ids == HOOD_ID
    if hood.any():  # fixed in the camera frame
        cam[hood] = world_to_camera(points[hood], cam_now)
    ahead = cam[:, 2] > 1e-3
    uv = np.full((len(cam), 2), np.nan)
    uv[ahead] = project(cam[ahead], K)
    inside = ahead & (uv[:, 0] > -0.5) & (uv[:, 0] < w - 0.5) & (uv[:, 1] > -0.5) & (uv[:, 1] < h - 0.5)
    flow = np.zeros((h, w, 2), np.float32)
    valid = np.zeros((h, w), bool)
    flow[v[inside], u[inside]] = (uv[inside] - np.stack([u, v], axis=1)[inside]).astype(np.float32)
    valid[v[inside], u[inside]] = True
    return flow, valid


def episode_flow(depth, instance, rig, scene, instances, t: float, t_next: float) -> np.ndarray:
    """The ``flow`` buffer of the frame at ``t``: HxWx3 float32 (u, v, valid), towards ``t_next``."""
    world_from_gl = rig.world_from_camera
    cam_now = world_from_gl(scene.ego.pose(t)) @ CV_FROM_GL
    cam_next = world_from_gl(scene.ego.pose(t_next)) @ CV_FROM_GL
    moves = {}
    for inst in instances:
        if inst.actor >= 0:
            actor = scene.actors[inst.actor]
            moves[inst.id] = actor.pose(t_next) @ np.linalg.inv(actor.pose(t))
    flow, valid = forward_flow(depth, instance, rig.K, cam_now, cam_next, moves)
    return np.concatenate([flow, valid[..., None].astype(np.float32)], axis=-1)
