"""The BEV's compiled pixel transforms (harness.sensors.bev_pixels) against the NumPy formulas they
replaced, bit for bit, and one pixel by hand."""
from __future__ import annotations

import math

import numpy as np

from controller.vehicle import EgoState
from harness.sensors.bev import EGO_ROW, RES, SIZE, VEHICLES, BevRenderer
from harness.sensors.bev_pixels import boxes_to_pixels, points_to_pixels, points_within
from harness.sim.plan import build_plan
from harness.sim.stop_signs import stop_passages
from harness.sim.world import VEHICLE, Snapshot
from scenarios import resolve_set
from scenarios.routefile import read_routes
from sumo_nets import load_net


def numpy_corners(xy: np.ndarray, yaw: np.ndarray, size: np.ndarray) -> np.ndarray:
    """(K, 4, 2) box corners by the plain NumPy formula: the reference for boxes_to_pixels."""
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    dx = np.array([1.0, 1.0, -1.0, -1.0]) * (size[:, 0] / 2)[:, None]
    dy = np.array([1.0, -1.0, -1.0, 1.0]) * (size[:, 1] / 2)[:, None]
    out = np.empty(dx.shape + (2,))
    x, y = out[..., 0], out[..., 1]
    np.add(xy[:, 0, None], c * dx, out=x)
    x -= s * dy
    np.add(xy[:, 1, None], s * dx, out=y)
    y += c * dy
    return out


def numpy_pixels(pts: np.ndarray, ex: float, ey: float, yaw: float) -> np.ndarray:
    """World points -> BEV pixels x 16 by the plain NumPy formula: the reference for points_to_pixels."""
    c, s = math.cos(yaw), math.sin(yaw)
    d = np.asarray(pts, dtype=float) - (ex, ey)
    dx, dy = d[:, 0], d[:, 1]
    uv = np.empty_like(d)
    np.subtract(SIZE / 2, (-s * dx + c * dy) / RES, out=uv[:, 0])
    np.subtract(EGO_ROW, (c * dx + s * dy) / RES, out=uv[:, 1])
    uv *= 16
    return np.rint(uv, out=uv).astype(np.int32)


def raster(ex: float, ey: float, yaw: float) -> tuple:
    return ex, ey, math.cos(yaw), math.sin(yaw), SIZE / 2, float(EGO_ROW), RES


def test_points_and_box_corners_give_numpys_pixels_bit_for_bit():
    rng = np.random.default_rng(3)
    for _ in range(300):
        ex, ey, yaw = *rng.uniform(-2000.0, 2000.0, 2), float(rng.uniform(-math.pi, math.pi))
        pts = np.array([ex, ey]) + rng.normal(0.0, 30.0, size=(int(rng.integers(0, 400)), 2))
        np.testing.assert_array_equal(points_to_pixels(pts, *raster(ex, ey, yaw)), numpy_pixels(pts, ex, ey, yaw))
        k = int(rng.integers(0, 40))
        table = np.column_stack([np.array([ex, ey]) + rng.normal(0.0, 30.0, size=(k, 2)),
                                 rng.uniform(-4.0, 4.0, k), rng.uniform(0.3, 12.0, (k, 2))])
        xy, yaw_k, size = table[:, :2], table[:, 2], table[:, 3:5]  # strided views, as a Snapshot's
        got = boxes_to_pixels(xy, np.cos(yaw_k), np.sin(yaw_k), size, *raster(ex, ey, yaw))
        want = numpy_pixels(numpy_corners(xy, yaw_k, size).reshape(-1, 2), ex, ey, yaw).reshape(-1, 4, 2)
        np.testing.assert_array_equal(got, want)


def test_the_route_near_the_ego_is_numpys_selection_bit_for_bit():
    rng = np.random.default_rng(4)
    for _ in range(300):
        x, y = rng.uniform(-2000.0, 2000.0, 2)
        pts = np.array([x, y]) + rng.normal(0.0, 40.0, size=(int(rng.integers(0, 600)), 2))
        want = pts[np.hypot(pts[:, 0] - x, pts[:, 1] - y) < 45.0]
        np.testing.assert_array_equal(points_within(pts, x, y, 45.0), want)
    # on the circle (45 m east, north, 27-36-45) is out, a metre's millionth inside is in
    x, y = 1234.5, -678.25
    pts = np.array([[x + 45.0, y], [x, y + 45.0], [x - 27.0, y - 36.0], [x + 45.0 - 1e-6, y], [x, y]])
    np.testing.assert_array_equal(points_within(pts, x, y, 45.0), pts[3:])
    assert points_within(np.zeros((0, 2)), x, y, 45.0).shape == (0, 2)


def test_a_pixel_by_hand():
    # ego at (100, 50) heading north (yaw pi/2): a point 12 m north and 3 m west of it is
    # 12 m ahead and 3 m to the left: column 32 - 3 / 0.75 = 28, row 48 - 12 / 0.75 = 32
    px = points_to_pixels(np.array([[97.0, 62.0]]), *raster(100.0, 50.0, math.pi / 2))
    np.testing.assert_array_equal(px, [[28 * 16, 32 * 16]])
    # a 4 m x 2 m box there, aligned with the ego: corners 2 m ahead / behind, 1 m each side
    box = boxes_to_pixels(np.array([[97.0, 62.0]]), np.array([0.0]), np.array([1.0]), np.array([[4.0, 2.0]]),
                          *raster(100.0, 50.0, math.pi / 2))
    front_left = (28 - 1 / RES, 32 - 2 / RES)  # the first corner: +length/2 along, +width/2 across (left)
    np.testing.assert_array_equal(box[0, 0], np.rint(np.array(front_left) * 16))


def test_a_float32_snapshot_is_drawn_as_its_float64_copy():
    # the kernels take float64; draw casts a float32 snapshot (a dataset written elsewhere)
    route = read_routes(resolve_set("town12_smoke"))[1][0]
    plan = build_plan(route, load_net(route.town))
    x, y, yaw = plan.path.pose(20.0)
    ego = EgoState(x, y, yaw, 5.0)
    ahead = np.array([[x + 10 * math.cos(yaw), y + 10 * math.sin(yaw)]])  # a car 10 m ahead
    snap32 = Snapshot(["v"], ahead.astype(np.float32), np.array([yaw], dtype=np.float32), np.array([5.0]),
                      np.array([[4.5, 1.9]], dtype=np.float32), np.array([VEHICLE]), math.nan)
    snap64 = Snapshot(["v"], snap32.xy.astype(float), snap32.yaw.astype(float), snap32.speed,
                      snap32.size.astype(float), snap32.cls, math.nan)
    r = BevRenderer.for_town(route.town)
    stops = [True] * len(stop_passages(plan))
    bev32, bev64 = r.draw(ego, snap32, plan, [], [], stops), r.draw(ego, snap64, plan, [], [], stops)
    np.testing.assert_array_equal(bev32, bev64)
    assert bev64[VEHICLES].any()  # the car is drawn
