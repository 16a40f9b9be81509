"""SimLingo's controller (controller.simlingo) with hand-computed values, and the student
agent's plumbing (checkpoint in, Control and Prediction out)."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from controller.lookahead import lookahead_point
from controller.pid import LAT_KI, LAT_KP, SPEED_KD, SPEED_KI, SPEED_KP, LateralPID
from controller.simlingo import PATH_STEP, SimLingoController, desired_speed, resample_path
from controller.vehicle import Control
from harness.loop.agent import Prediction, load_agent

STRAIGHT = np.stack([np.arange(20.0), np.zeros(20)], 1)  # 0..19 m straight ahead


def wps_at(speed: float) -> np.ndarray:
    """Speed waypoints (10, 2) of a constant speed [m/s] straight ahead: x = v (k + 1) 0.25 s."""
    return np.stack([speed * 0.25 * np.arange(1, 11), np.zeros(10)], 1)


def line(angle_deg: float) -> np.ndarray:
    a = math.radians(angle_deg)
    s = np.arange(20.0)
    return np.stack([s * math.cos(a), s * math.sin(a)], 1)


def test_desired_speed_is_twice_the_distance_from_the_first_to_the_third_waypoint():
    wps = np.zeros((10, 2))
    wps[0], wps[2] = (1.0, 0.0), (4.0, 4.0)  # 5 m apart
    assert desired_speed(wps) == pytest.approx(10.0)
    assert desired_speed(wps_at(6.0)) == pytest.approx(6.0)


def test_straight_path_at_the_current_speed_gives_zero_steer_and_steady_throttle():
    c = SimLingoController()
    controls = [c.step(STRAIGHT, wps_at(5.0), 5.0) for _ in range(30)]
    # zero speed error: the PID's window of zeros stays zero; the vehicle model keeps speed
    # below 0.3 throttle, so 0 is the steady cruise command
    assert all(ctl == Control(0.0, 0.0, 0.0) for ctl in controls)


def test_speed_pid_values_by_hand():
    assert (SPEED_KP, SPEED_KI, SPEED_KD) == (1.75, 1.0, 2.0)  # SimLingo's speed PID gains
    c = SimLingoController()
    first = c.step(STRAIGHT, wps_at(5.0), 4.5)  # error 0.5 m/s
    # Kp e + Ki mean(window of 20: one 0.5) + Kd (0.5 - 0) = 0.875 + 0.025 + 1.0 -> clipped to 1
    assert first.throttle == 1.0
    assert first.brake == 0.0
    second = c.step(STRAIGHT, wps_at(5.0), 4.5)
    # SimLingo's gains (Kp 1.75, Ki 1.0, Kd 2.0): 1.75 x 0.5 + 1.0 x (0.5 + 0.5) / 20 + 2.0 x 0
    assert second.throttle == pytest.approx(0.925, abs=1e-12)
    small = SimLingoController().step(STRAIGHT, wps_at(5.0), 4.8)  # error 0.2 m/s, not clipped
    assert small.throttle == pytest.approx(1.75 * 0.2 + 1.0 * 0.2 / 20 + 2.0 * 0.2, abs=1e-12)  # 0.76
    big = SimLingoController().step(STRAIGHT, wps_at(8.0), 2.0)  # error clipped to 1 m/s
    assert big.throttle == 1.0


@pytest.mark.parametrize("angle, sign", [(9.0, -1.0), (-9.0, 1.0)])
def test_a_path_bending_to_one_side_steers_to_that_side(angle, sign):
    # a line at +9 deg (to the left, y > 0): the lookahead point (2.4 m at rest) lies at 9 deg,
    # error = -9/90 = -0.1; first step: (Kp + Ki) * error (derivative 0, window mean = error)
    c = SimLingoController()
    ctl = c.step(line(angle), wps_at(0.0), 0.0)
    assert ctl.steer == round(sign * (LAT_KP + LAT_KI) * 0.1, 3) == sign * 0.376  # steer > 0 = right
    assert c.step(line(angle), wps_at(0.0), 0.0).steer == ctl.steer  # same error, zero derivative


def test_lookahead_grows_with_speed():
    # a path straight for 5 m, then at 90 deg to the left: at rest the 2.4 m point is on the
    # straight part (zero steer); at 50 km/h the lookahead is 5.07 m, past the corner
    path = np.vstack([STRAIGHT[:6], np.stack([np.full(14, 5.0), np.arange(1.0, 15.0)], 1)])
    assert SimLingoController().step(path, wps_at(0.0), 0.0).steer == 0.0
    assert SimLingoController().step(path, wps_at(50 / 3.6), 50 / 3.6).steer < 0.0


@pytest.mark.parametrize("desired, speed, brake", [
    (0.39, 0.0, True), (0.41, 0.0, False),  # desired below 0.4 m/s
    (5.0, 5.55, True), (5.0, 5.45, False),  # speed / desired above 1.1
])
def test_brake_rule(desired, speed, brake):
    ctl = SimLingoController().step(STRAIGHT, wps_at(desired), speed)
    assert (ctl.brake == 1.0) == brake
    if brake:
        assert ctl.throttle == 0.0
    if not brake and speed == 0.0:
        assert ctl.throttle > 0.0


def test_creep_after_forty_seconds_standing():
    # standing = below 0.1 m/s, so 0.05 m/s counts. 40 s at 20 Hz = 800 ticks of braking (the
    # network's command: desired speed 0); on the 801st the creep starts: 0.75 s = 15 ticks of
    # throttle 0.4, brake released; then the network's brake again
    c = SimLingoController()
    stopped = [c.step(STRAIGHT, wps_at(0.0), 0.05) for _ in range(800)]
    assert all(ctl.brake == 1.0 for ctl in stopped)
    creep = [c.step(STRAIGHT, wps_at(0.0), 0.05) for _ in range(15)]
    assert all(ctl.throttle == 0.4 and ctl.brake == 0.0 for ctl in creep)
    assert c.step(STRAIGHT, wps_at(0.0), 0.05).brake == 1.0  # back to the network's command


def test_resample_path_every_tenth_of_a_metre_from_the_origin():
    pts = resample_path(np.array([[0.0, 0.0], [0.0, 1.0]]))  # 1 m to the left
    np.testing.assert_allclose(pts, np.stack([np.zeros(10), np.arange(1, 11) * 0.1], 1), atol=1e-12)
    np.testing.assert_array_equal(resample_path(np.zeros((20, 2))), [[0.0, 0.0]])  # degenerate



def _random_paths(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """Paths (20, 2) [m] as a network might give them: winding, some with repeated points
    (zero-length segments), some standing still, some short, some doubling back."""
    out = []
    for k in range(n):
        p = np.cumsum(rng.normal(0.6, 0.6, size=(20, 2)), 0)
        if k % 3 == 0:
            p[rng.integers(0, 19)] = p[rng.integers(0, 19)]  # a repeated point
        if k % 10 == 1:
            p[:] = 0.0  # standing
        if k % 10 == 2:
            p *= 0.004  # shorter than one resampling step or a few
        if k % 10 == 3:
            p[10:] = p[9::-1]  # out and back
        out.append(p)
    return out


def test_the_compiled_lookahead_point_equals_resampling_and_the_pid_target_bit_for_bit():
    # controller.lookahead replicates resample_path + LateralPID.target operation by operation;
    # equal doubles, not close ones, so the closed loop's records cannot move (exact ==)
    rng = np.random.default_rng(7)
    paths = _random_paths(rng, 4000) + [STRAIGHT, line(30.0), line(-89.0), np.zeros((1, 2))]
    speeds = rng.uniform(0.0, 30.0, size=len(paths))  # the lookahead spans 2.4 .. 10.5 m
    for path, v in zip(paths, speeds):
        want = LateralPID().target(resample_path(path), v)
        assert lookahead_point(path, LateralPID.lookahead(v), PATH_STEP) == want
    assert lookahead_point(np.float32(STRAIGHT), 5.0, PATH_STEP) == (5.0, 0.0)  # a float32 path (ONNX output)
    with pytest.raises(ValueError, match="non-finite path"):
        lookahead_point(np.full((20, 2), np.nan), 5.0, PATH_STEP)


def test_the_lookahead_point_by_hand():
    # straight ahead at 36 km/h: lookahead clip(0.9755 * 36 + 1.915, 24, 105) = 37.03 -> 3.703 m;
    # resampled every 0.1 m, the summed distance reaches it at the 38th point, x = 3.8 m
    assert LateralPID.lookahead(10.0) == pytest.approx(3.7034, abs=1e-4)
    x, y = lookahead_point(STRAIGHT, LateralPID.lookahead(10.0), PATH_STEP)
    assert (x, y) == (pytest.approx(3.8, abs=1e-12), 0.0)
    assert lookahead_point(STRAIGHT[:2] * 0.05, 3.0, PATH_STEP) == (0.05, 0.0)  # 5 cm long: its last point

@pytest.mark.parametrize("speed_input", [True, False])
def test_the_student_runs_its_network_only_for_new_inputs_and_repeats_give_its_outputs(tmp_path, speed_input):
    """A tick whose inputs equal the previous tick's as the network sees them (binarised
    BEV, float32 target point, and speed if the network takes it) reuses the previous
    outputs; every output equals a fresh network call on that tick's inputs, bit for bit,
    so records cannot change."""
    from model.cache import binarize
    from model.checkpoint import save_checkpoint
    from model.network import NetConfig, Student
    torch.manual_seed(0)
    agent = load_agent("student")
    agent.setup(str(save_checkpoint(tmp_path / "student.pt", Student(NetConfig(speed_input=speed_input)), {})))
    rng = np.random.default_rng(0)
    a = (rng.random((9, 64, 64)) < 0.2).astype(np.uint8) * 255
    b = a.copy()
    b[4, 20:24, 30:34] = 255 - b[4, 20:24, 30:34]  # a vehicle moved
    a_dim = np.where(a > 0, 200, 0).astype(np.uint8)  # the same raster once binarised
    tp = np.array([12.0, 0.5])
    ticks = [(a, tp, 3.0), (a, tp.copy(), 3.0), (a_dim, tp, 3.0), (a, tp, 3.0 + 1e-12),  # repeats
             (b, tp, 3.0), (a, tp, 3.0), (a, tp + 1e-3, 3.0), (a, tp + 1e-3, 0.0)]  # new inputs
    for k, (bev, target, speed) in enumerate(ticks):
        path, wps = agent.predict(bev, target, speed)
        fresh_path, fresh_wps = agent.infer(binarize(bev), target, speed)
        np.testing.assert_array_equal(path, fresh_path, err_msg=f"tick {k}")
        np.testing.assert_array_equal(wps, fresh_wps, err_msg=f"tick {k}")
    # 3 of the 8 ticks reuse the outputs; without the speed input the last one too (only its speed is new)
    calls = 5 if speed_input else 4
    assert (agent.frames, agent.network_calls) == (8, calls)
    path[:] = np.nan  # a caller writing into the outputs does not reach the agent's copy
    assert np.isfinite(agent.predict(a, tp + 1e-3, 0.0)[0]).all()
    assert agent.network_calls == calls
    agent.setup(str(tmp_path / "student.pt"))  # a new route forgets the last inputs
    agent.predict(a, tp + 1e-3, 0.0)
    assert (agent.frames, agent.network_calls) == (1, 1)


def test_student_agent_returns_a_control_and_its_waypoints(tmp_path):
    from model.checkpoint import save_checkpoint
    from model.network import NetConfig, Student
    torch.manual_seed(0)
    ckpt = save_checkpoint(tmp_path / "student.pt", Student(NetConfig()), {})
    agent = load_agent("student")
    agent.setup(str(ckpt))
    assert sorted(s["type"] for s in agent.sensors()) == ["bev", "speed", "target_point"]
    bev = np.zeros((9, 64, 64), np.uint8)
    control, pred = agent.run_step({"bev": bev, "target_point": np.array([12.0, 0.0]), "speed": 3.0}, 0.05)
    assert isinstance(control, Control)
    assert control.is_finite()
    assert isinstance(pred, Prediction)
    assert pred.path.shape == (20, 2)
    assert pred.speed_wps.shape == (10, 2)
    assert agent.network_calls == 1
    agent._forget()  # else the same inputs would return the stored outputs without a network call
    path, wps = agent.predict(bev, np.array([12.0, 0.0]), 3.0)
    assert agent.network_calls == 1  # a second, fresh run of the network ...
    np.testing.assert_array_equal(path, pred.path)  # ... gives the same outputs: inference is deterministic
    np.testing.assert_array_equal(wps, pred.speed_wps)
    with pytest.raises(ValueError, match="agent-config"):
        load_agent("student").setup(None)
