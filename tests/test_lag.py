"""Lag figures (scimm.lag): alignment offset, standstill frames, mode switches."""
from __future__ import annotations

import numpy as np

from scimm import pathspeed as ps
from scimm.lag import OFFSETS, lag_tables, offset_errors, stood, switches


def test_a_series_delayed_by_two_frames_aligns_at_offset_two():
    expert = np.sin(np.arange(60) / 3.0)
    late = np.concatenate([expert[:2], expert[:-2]])  # teacher_t = expert_(t-2)
    err = offset_errors(late, expert, np.zeros(60, dtype=int))
    mae = err[:, 0, 0] / err[:, 0, 1]
    assert OFFSETS[int(np.argmin(mae))] == 2
    assert mae[OFFSETS.index(2)] == 0.0
    # counts: offset k compares the 60 - |k| frames whose t - k exists
    np.testing.assert_array_equal(err[:, 0, 1], [60 - abs(k) for k in OFFSETS])


def test_stood_needs_three_still_frames_in_a_row():
    v = np.array([1.0, 0.0, 0.0, 0.0, 0.05, 0.5, 0.0, 0.0, 0.1, 0.0])
    np.testing.assert_array_equal(stood(v), [0, 0, 0, 1, 1, 0, 0, 0, 1, 1])


def test_switches_count_changes_of_the_argmax():
    mu = np.eye(5)[[0, 0, 1, 1, 0, 2, 2]]
    assert switches(mu) == 3


def test_lag_tables_on_a_teacher_one_frame_late():
    """Raw speeds ramp down 8 -> 0 and stand; the teacher is the raw labels one frame late.
    Its v(0) offset is +1; where the expert has stood 0.5 s the late teacher stands too."""
    T = 20
    v0 = np.maximum(8.0 - np.arange(T), 0.0)  # stops at frame 8
    speed = np.repeat(v0[:, None], 10, axis=1)
    x = np.zeros((T, 5))
    x[:, 1] = 0.01 * np.arange(T)  # a curvature that changes: c0 stays 0, aligned
    path = ps.state_path(x)
    late = np.concatenate([speed[:1], speed[:-1]])
    ep = {"raw": {"path": path, "speed": speed}, "v": v0,
          "fixed": {"path": path, "speed": late, "mu": np.eye(5)[[0] * T]},
          "scimm": {"path": path, "speed": speed, "mu": np.eye(5)[[0] * T]}}
    align, still = lag_tables([ep], ("fixed", "scimm"))
    a = align.set_index(["mode", "method"])
    assert a.loc[("Cruise", "Fixed-IMM"), "v0_offset"] == 1
    assert a.loc[("Cruise", "SC-IMM"), "v0_offset"] == 0
    assert a.loc[("Cruise", "SC-IMM"), "v0_mae"] == 0.0
    s = still.set_index("method")
    # stood: frames 10..19 (v = 0 at 8, 9, 10 first); the late teacher says v0[9] = 0 there too
    assert s.loc["Original Raw Expert", "stood_frames"] == 10
    assert s.loc["Fixed-IMM", "standing_share"] == 1.0
    assert s.loc["Fixed-IMM", "switches_per_min"] == 0.0


def test_lag_tables_give_the_offset_0_mae_all_frames_and_switches_per_minute():
    """The raw speeds ramp 8 -> 0 over frames 0-8 and stand; the Fixed-IMM labels are one
    frame late, so frames 1-8 are 1 m/s off: v0_mae (offset 0) = 8 / 20 = 0.4 (the best
    offset, +1, would give 0). All 20 frames are Cruise (the offset 0 count; offset -4
    compares only 16). Its dominant mode changes at frames 5, 10 and 15: 3 switches in
    20 frames at 4 Hz = 5 s, 3 / (5 / 60) = 36.0 per minute."""
    T = 20
    v0 = np.maximum(8.0 - np.arange(T), 0.0)
    speed = np.repeat(v0[:, None], 10, axis=1)
    path = ps.state_path(np.zeros((T, 5)))
    late = np.concatenate([speed[:1], speed[:-1]])
    ep = {"raw": {"path": path, "speed": speed}, "v": v0,
          "fixed": {"path": path, "speed": late, "mu": np.eye(5)[[0] * 5 + [1] * 5 + [0] * 5 + [2] * 5]},
          "scimm": {"path": path, "speed": speed, "mu": np.eye(5)[[0] * T]}}
    align, still = lag_tables([ep], ("fixed",))
    a = align.set_index(["mode", "method"])
    assert a.loc[("Cruise", "Fixed-IMM"), "v0_mae"] == 0.4
    assert a.loc[("Cruise", "Fixed-IMM"), "frames"] == 20
    assert still.set_index("method").loc["Fixed-IMM", "switches_per_min"] == 36.0


def test_a_teacher_v0_of_0_30_counts_as_standing_and_0_31_not():
    """The expert stands (v = 0) for 5 frames: frames 2-4 have stood 0.5 s. The teacher's
    v(0) there is 0.30, 0.31, 0.0: standing share 2 / 3, and the mean v(0) is
    0.61 / 3 = 0.20333 (the median would be 0.30)."""
    T = 5
    path = ps.state_path(np.zeros((T, 5)))
    teacher = np.repeat(np.array([1.0, 1.0, 0.30, 0.31, 0.0])[:, None], 10, axis=1)
    mu = np.eye(5)[[0] * T]
    ep = {"raw": {"path": path, "speed": np.zeros((T, 10))}, "v": np.zeros(T),
          "fixed": {"path": path, "speed": teacher, "mu": mu}, "scimm": {"path": path, "speed": teacher, "mu": mu}}
    s = lag_tables([ep], ("fixed",))[1].set_index("method")
    assert s.loc["Fixed-IMM", "stood_frames"] == 3
    assert s.loc["Fixed-IMM", "standing_share"] == 2 / 3
    assert abs(s.loc["Fixed-IMM", "stood_mean_v0"] - 0.61 / 3) < 1e-15  # float sum order only


def test_red_light_frames_move_above_0_5_m_s_and_horizons_are_label_speeds_5_and_10():
    """Two red-light frames at 0.5 and 0.51 m/s: only the second is braking (> 0.5). Its
    label speeds are 0, 1, ..., 9 m/s: the 1.25 s horizon is the 5th (4.0), the 2.5 s one
    the 10th (9.0); the other frame's speeds are 100 m/s higher, so picking it would show."""
    from scimm.lag import stops_starts
    speed = np.stack([100.0 + np.arange(10), np.arange(10.0)])
    ep = {"raw": {"speed": speed}, "fixed": {"speed": speed}, "v": np.array([0.5, 0.51]),
          "light": np.array([True, True]), "travel": np.zeros(2)}
    df = stops_starts([ep], ("fixed",)).set_index(["situation", "method"])
    row = df.loc[("red light", "Original Raw Expert")]
    assert row["frames"] == 1
    assert row["v_1.25 s"] == 4.0
    assert row["v_2.5 s"] == 9.0


def test_stops_starts_compare_label_speeds_ahead_in_red_light_and_start_frames():
    """Six frames: 0-1 moving with a red light, 2 moving without one, 3 standing and staying,
    4-5 standing and starting off. The teacher's labels are the raw ones + 0.5 m/s in every
    frame, so its excess is +0.5 in both situations; the raw means are picked frames only."""
    from scimm.lag import stops_starts
    speed = np.array([[6.0] * 10, [4.0] * 10, [9.0] * 10, [0.0] * 10, [2.0] * 10, [1.0] * 10])
    ep = {"raw": {"speed": speed}, "fixed": {"speed": speed + 0.5},
          "v": np.array([6.0, 4.0, 9.0, 0.0, 0.05, 0.0]),
          "light": np.array([True, True, False, True, False, False]),
          "travel": np.array([15.0, 10.0, 22.0, 0.2, 5.0, 0.5])}
    df = stops_starts([ep], ("fixed",)).set_index(["situation", "method"])
    assert df.loc[("red light", "Original Raw Expert"), "frames"] == 2  # frame 3 stands: not braking
    assert df.loc[("red light", "Original Raw Expert"), "v_2.5 s"] == 5.0  # (6 + 4) / 2
    assert df.loc[("red light", "Fixed-IMM"), "v_1.25 s"] == 5.5
    assert df.loc[("red light", "Fixed-IMM"), "excess_2.5 s"] == 0.5
    assert df.loc[("start", "Original Raw Expert"), "frames"] == 2  # 0.5 m in 2.5 s counts, 0.2 m not
    assert df.loc[("start", "Original Raw Expert"), "v_2.5 s"] == 1.5
    assert df.loc[("start", "Fixed-IMM"), "excess_1.25 s"] == 0.5
    assert df.loc[("start", "Original Raw Expert"), "excess_2.5 s"] == 0.0
