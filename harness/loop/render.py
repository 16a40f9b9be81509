"""``sumo-scimm render``: a route driven by an agent, as a BEV video with the predicted
waypoints drawn on it, and a PNG of the driven path over the map (for people)."""
from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from harness.sensors.bev import BevRenderer, colorize, ego_to_image
from controller.ego import DEFAULT_VEHICLE
from files.atomic import write_atomic
from harness.loop.episode import EpisodeResult, run_episode
from scenarios.routefile import Route

FPS = 20  # one video frame per simulation step (real time)
SCALE = 4  # video pixels per BEV pixel


def render_route(route: Route, agent: str, agent_config: str | None, seed: int, video: Path,
                 every: int = 1, vehicle: str = DEFAULT_VEHICLE) -> tuple[EpisodeResult, Path]:
    """Drive the route with ego model ``vehicle`` (controller.ego), write the BEV video (every
    ``every``-th tick) and ``<video>.png``. The video is written beside ``video`` and renamed
    to it once whole: a failed or interrupted render leaves the earlier file (if any) as it
    was and no partial one."""
    bev = BevRenderer.for_town(route.town)
    video.parent.mkdir(parents=True, exist_ok=True)
    size = 64 * SCALE
    part = video.with_name(f".{video.stem}.part{video.suffix}")  # the suffix names the container to OpenCV
    writer = cv2.VideoWriter(str(part), cv2.VideoWriter_fourcc(*"mp4v"), FPS / every, (size, size))
    if not writer.isOpened():
        raise RuntimeError(f"OpenCV cannot write {video} (mp4v codec)")
    path_xy = []
    state = {}

    def on_frame(f):
        tick, ego, pred = f.tick, f.ego, f.pred
        path_xy.append((ego.x, ego.y))
        state["plan"] = f.plan
        if tick % every:
            return
        img = colorize(bev.render(ego, f.snap, f.plan, f.lights, f.props, f.stops), SCALE)
        if pred is not None:
            for pts, col in ((pred.path, (0, 255, 0)), (pred.speed_wps, (255, 0, 255))):
                if pts is not None:
                    for u, v in ego_to_image(pts, SCALE):
                        cv2.circle(img, (int(u), int(v)), 2, col, -1)
        cv2.putText(img, f"t={tick * 0.05:5.1f}s v={ego.v:4.1f}m/s", (4, 12), cv2.FONT_HERSHEY_SIMPLEX,
                    0.4, (255, 255, 255), 1, cv2.LINE_AA)
        writer.write(img)

    try:
        try:
            res = run_episode(route, agent, agent_config, seed, on_frame=on_frame, vehicle=vehicle)
        finally:
            writer.release()
        png = video.with_suffix(".png")
        image = _path_image(bev, state.get("plan", res.plan), np.array(path_xy).reshape(-1, 2))
        write_atomic(png, cv2.imencode(".png", image)[1].tobytes())
        os.replace(part, video)
    finally:
        part.unlink(missing_ok=True)
    return res, png


def _path_image(bev: BevRenderer, plan, driven: np.ndarray) -> np.ndarray:
    """The map around the route (road grey, sidewalks light), route green, driven path red."""
    pts = plan.xy if plan is not None else driven
    if len(driven):
        pts = np.vstack([pts, driven])
    if not len(pts):  # no plan and nothing driven (the route failed before its first tick)
        return np.full((64, 64, 3), 255, dtype=np.uint8)
    ppm = 4.0  # [px / m]
    lo, hi = pts.min(0) - 30.0, pts.max(0) + 30.0
    w, h = (int(v) for v in (hi - lo) * ppm)
    img = np.full((h, w, 3), 255, dtype=np.uint8)
    # the static map is at bev.MAP_PPM; sample it for this window
    k = ppm / (1 / 0.75)
    m = np.array([[k, 0, -((lo[0] - bev.x0) / 0.75) * k], [0, k, -((bev.y1 - hi[1]) / 0.75) * k]])
    base = cv2.warpAffine(bev.map, m, (w, h), flags=cv2.INTER_LINEAR)
    img[base[:, :, 0] > 64] = (170, 170, 170)
    img[base[:, :, 2] > 64] = (215, 225, 230)
    to_px = lambda p: np.stack([(p[:, 0] - lo[0]) * ppm, (hi[1] - p[:, 1]) * ppm], 1).astype(np.int32)  # noqa: E731
    if plan is not None:
        cv2.polylines(img, [to_px(plan.xy)], False, (60, 170, 60), 6, cv2.LINE_AA)
    if len(driven) >= 2:
        cv2.polylines(img, [to_px(driven)], False, (40, 40, 230), 2, cv2.LINE_AA)
    return img
