"""The hardware bridge's ROS-free safety layer: the arm limits file and its loader, the
trajectory checks (each refuses what it must and passes its boundary), the speed-scaling cap,
the force ceiling, the watchdog and the E-stop latch; and the default limits against the via-
point trajectories the executor really sends (MuJoCo world, every WRT of two objects)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import yaml

from rrg_hw_bridge.arm_limits import DEFAULT_ARM_LIMITS, ArmLimits, load_arm_limits
from rrg_hw_bridge.safety import (
    RATE_REL_TOL,
    WORKSPACE_POINTS,
    EStop,
    ForceCeiling,
    Refusal,
    SafetyCode,
    Watchdog,
    check_accelerations,
    check_positions,
    check_shape,
    check_trajectory,
    check_velocities,
    check_workspace,
    scale_time,
    segment_velocities,
    via_point_accelerations,
    workspace_points,
)
from rrg_models import wam
from rrg_models.config import WORLD

LIMITS = load_arm_limits()
NAMES = LIMITS.joint_names
Q0 = wam.HOME_Q.copy()  # hand 0.55 m above the table, pointing down
LIFT = 1.0 + 1e-6  # just past a limit (well beyond the checks' round-off slack)


def with_box(lo, hi) -> ArmLimits:
    """The default limits with another workspace box [m]."""
    return ArmLimits(
        LIMITS.joint_names,
        LIMITS.lower,
        LIMITS.upper,
        LIMITS.max_velocity,
        LIMITS.max_acceleration,
        np.asarray(lo, float),
        np.asarray(hi, float),
        "test",
    )


def one_joint_move(joint: int, dq: float, duration: float) -> tuple[np.ndarray, np.ndarray]:
    """Two via-points: home, then home with ``joint`` moved by dq [rad] after duration [s]."""
    q = np.stack([Q0, Q0])
    q[1, joint] += dq
    return q, np.array([0.0, duration])


def bang_bang(joint: int, accel: float, half: float = 0.1, h: float = 0.02):
    """Via-points every h [s] of a rest-to-rest move of ``joint``: accel [rad/s²] for ``half``
    seconds, then -accel. The via-point estimate is exactly ±accel at the ends and during
    each phase."""
    t = np.arange(0.0, 2 * half + h / 2, h)
    s = np.where(t <= half, accel * t**2 / 2, accel * (half**2 - (2 * half - t) ** 2 / 2))
    q = np.repeat(Q0[None], len(t), axis=0)
    q[:, joint] += s
    return q, t


# ------------------------------------------------------------------ arm limits file
def test_default_limits_are_barretts():
    assert DEFAULT_ARM_LIMITS.is_file()
    assert LIMITS.name == "barrett_wam7"
    assert NAMES == tuple(f"wam_j{i}_joint" for i in range(1, 8))
    np.testing.assert_array_equal(LIMITS.lower, [-2.6, -2.0, -2.8, -0.9, -4.76, -1.6, -3.0])
    np.testing.assert_array_equal(LIMITS.upper, [2.6, 2.0, 2.8, 3.1, 1.24, 1.6, 3.0])
    np.testing.assert_array_equal(LIMITS.max_velocity, np.full(7, 1.5))
    assert (LIMITS.max_acceleration > 0).all()
    # The box holds the table's extent and the base, its floor above the table top.
    assert LIMITS.workspace_min[0] < 0.0 and LIMITS.workspace_max[0] >= WORLD.table_x[1]
    assert LIMITS.workspace_min[1] <= WORLD.table_y[0]
    assert LIMITS.workspace_max[1] >= WORLD.table_y[1]
    assert LIMITS.workspace_min[2] > WORLD.table_top_z
    with pytest.raises(ValueError):
        LIMITS.lower[0] = 0.0  # read-only


def _default_doc() -> dict:
    return yaml.safe_load(DEFAULT_ARM_LIMITS.read_text())


def _drop(d: dict, *keys):
    for k in keys[:-1]:
        d = d[k]
    del d[keys[-1]]


def _set(d: dict, value, *keys):
    for k in keys[:-1]:
        d = d[k]
    d[keys[-1]] = value


LOADER_ERRORS = [
    ("missing name", lambda d: _drop(d, "name"), "top level: missing key 'name'"),
    (
        "missing joint key",
        lambda d: _drop(d, "joints", "wam_j3_joint", "max_velocity"),
        "joints.wam_j3_joint: missing key 'max_velocity'",
    ),
    ("wrong count", lambda d: _drop(d, "joints", "wam_j7_joint"), "joints: 6 entries, expected 7"),
    (
        "non-finite",
        lambda d: _set(d, float("nan"), "joints", "wam_j2_joint", "upper"),
        "joints.wam_j2_joint.upper: nan is not a finite number",
    ),
    (
        "infinite",
        lambda d: _set(d, float("inf"), "joints", "wam_j5_joint", "max_acceleration"),
        "joints.wam_j5_joint.max_acceleration: inf is not a finite number",
    ),
    (
        "not a number",
        lambda d: _set(d, "fast", "joints", "wam_j1_joint", "max_velocity"),
        "joints.wam_j1_joint.max_velocity: expected a number, got 'fast'",
    ),
    (
        "lower = upper",
        lambda d: _set(d, 3.1, "joints", "wam_j4_joint", "lower"),
        "joints.wam_j4_joint: lower 3.1 rad must be below upper 3.1 rad",
    ),
    (
        "zero velocity",
        lambda d: _set(d, 0.0, "joints", "wam_j6_joint", "max_velocity"),
        "joints.wam_j6_joint.max_velocity: 0.0 rad/s must be > 0",
    ),
    (
        "negative acceleration",
        lambda d: _set(d, -1.0, "joints", "wam_j1_joint", "max_acceleration"),
        "joints.wam_j1_joint.max_acceleration: -1.0 rad/s² must be > 0",
    ),
    (
        "box min = max",
        lambda d: _set(d, [1.2, 0.7, 0.06], "workspace", "min"),
        "workspace: min x = 1.2 m must be below max x = 1.2 m",
    ),
    (
        "box size",
        lambda d: _set(d, [0.0, 1.0], "workspace", "max"),
        "workspace.max: expected 3 numbers",
    ),
    (
        "missing workspace",
        lambda d: _drop(d, "workspace"),
        "top level: missing key 'workspace'",
    ),
    (
        "missing source",
        lambda d: _drop(d, "source", "max_acceleration"),
        "source: missing key 'max_acceleration'",
    ),
    (
        "missing box source",
        lambda d: _drop(d, "workspace", "source", "z_min"),
        "workspace.source: missing key 'z_min'",
    ),
]


@pytest.mark.parametrize(
    "edit, message", [c[1:] for c in LOADER_ERRORS], ids=[c[0] for c in LOADER_ERRORS]
)
def test_loader_names_the_problem(tmp_path, edit, message):
    doc = _default_doc()
    edit(doc)
    path = tmp_path / "arm.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False, allow_unicode=True))
    with pytest.raises(ValueError) as info:
        load_arm_limits(path)
    assert message in str(info.value)
    assert str(path) in str(info.value)


def test_loader_rejects_invalid_yaml(tmp_path):
    path = tmp_path / "arm.yaml"
    path.write_text("joints: [unclosed\n")
    with pytest.raises(ValueError, match="not valid YAML"):
        load_arm_limits(path)
    path.write_text("- just a list\n")
    with pytest.raises(ValueError, match="expected a mapping"):
        load_arm_limits(path)


def test_loader_round_trip_keeps_joint_order(tmp_path):
    doc = _default_doc()
    _set(doc, 0.5, "joints", "wam_j7_joint", "max_velocity")
    path = tmp_path / "arm.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False, allow_unicode=True))
    limits = load_arm_limits(path)
    assert limits.joint_names == NAMES
    assert limits.max_velocity[6] == 0.5 and limits.max_velocity[5] == 1.5


# ------------------------------------------------------------------ codes
def test_safety_codes_are_guarded_move_codes():
    assert {c.name: int(c) for c in SafetyCode} == {
        "NONE": 0,
        "UNKNOWN": 100,
        "INVALID_TRAJECTORY": 101,
        "JOINT_LIMITS": 102,
        "CANCELED": 103,
        "TIMEOUT": 104,
        "JOINT_VELOCITY_LIMIT": 105,
        "JOINT_ACCELERATION_LIMIT": 106,
        "WORKSPACE": 107,
        "FORCE_LIMIT": 108,
        "STALE_DATA": 109,
        "SENSOR_FAULT": 110,
        "ESTOP": 111,
        "DRY_RUN": 112,
        "CONTROLLER_FAILED": 113,
    }


# ------------------------------------------------------------------ trajectory shape
def test_valid_slow_move_passes():
    q, t = one_joint_move(0, 0.5, 2.0)
    assert check_trajectory(q, t, LIMITS) is None
    assert check_trajectory(q.tolist(), t.tolist(), LIMITS) is None


SHAPE_CASES = [
    ("six joints", lambda q, t: (q[:, :6], t), "expected (M, 7)"),
    ("one point", lambda q, t: (q[:1], t[:1]), "need the start and at least one target"),
    ("times length", lambda q, t: (q, t[:1]), "times have shape (1,)"),
    ("flat q", lambda q, t: (q.ravel(), t), "expected (M, 7)"),
    (
        "nan angle",
        lambda q, t: (np.where(np.eye(2, 7, 3) > 0, np.nan, q), t),
        "wam_j4_joint is nan",
    ),
    ("inf time", lambda q, t: (q, np.array([0.0, np.inf])), "via-point 1: time is inf"),
    ("start not at 0", lambda q, t: (q, t + 0.1), "via-point 0 (the measured start) is at t = 0.1"),
    ("equal times", lambda q, t: (q, np.array([0.0, 0.0])), "times must increase strictly"),
    ("strings", lambda q, t: (q.astype(str), t), "must be real numbers"),
    ("ragged", lambda q, t: ([list(q[0]), list(q[1, :5])], t), "not rectangular"),
]


@pytest.mark.parametrize(
    "make, message", [c[1:] for c in SHAPE_CASES], ids=[c[0] for c in SHAPE_CASES]
)
def test_malformed_trajectories_are_invalid(make, message):
    q, t = make(*one_joint_move(1, 0.1, 1.0))
    refusal = check_trajectory(q, t, LIMITS)
    assert refusal is not None and refusal.code == SafetyCode.INVALID_TRAJECTORY
    assert refusal.check == "trajectory"
    assert message in refusal.message


def test_time_going_backwards_names_the_point():
    q = np.repeat(Q0[None], 4, axis=0)
    refusal = check_shape(q, np.array([0.0, 1.0, 2.0, 1.5]), LIMITS)
    assert refusal.code == SafetyCode.INVALID_TRAJECTORY
    assert "via-point 3 at t = 1.5 s is not after via-point 2 at t = 2 s" in refusal.message


# ------------------------------------------------------------------ positions
@pytest.mark.parametrize("joint", range(7))
@pytest.mark.parametrize("side", ["lower", "upper"])
def test_position_limits_boundary(joint, side):
    limit = getattr(LIMITS, side)[joint]
    q = np.stack([Q0, Q0, Q0])
    q[1, joint] = limit
    assert check_positions(q, LIMITS) is None  # exactly on the limit
    past = limit + (1e-6 if side == "upper" else -1e-6)
    q[1, joint] = past
    refusal = check_positions(q, LIMITS)
    assert refusal.code == SafetyCode.JOINT_LIMITS and refusal.check == "joint_limits"
    assert refusal.message.startswith(f"via-point 1: {NAMES[joint]} at {past:.4f} rad")
    assert f"{side} limit {limit:.4f} rad" in refusal.message


def test_position_refusal_comes_first_and_names_first_point():
    q = np.repeat(Q0[None], 4, axis=0)
    q[2, 3] = 3.2  # J4 past 3.1 rad, and a fast jump
    q[3, 0] = -2.7  # J1 past -2.6 rad
    refusal = check_trajectory(q, np.array([0.0, 0.01, 0.02, 0.03]), LIMITS)
    assert refusal.code == SafetyCode.JOINT_LIMITS
    assert "via-point 2: wam_j4_joint at 3.2000 rad is past its upper limit 3.1000 rad" in (
        refusal.message
    )
    assert "2 of 4 via-points" in refusal.message


# ------------------------------------------------------------------ velocity
@pytest.mark.parametrize("joint", range(7))
def test_velocity_limit_boundary(joint):
    vmax = LIMITS.max_velocity[joint]
    duration = 0.5  # s: the end accelerations 2 vmax / duration = 6 rad/s² stay within limits
    q, t = one_joint_move(joint, vmax * duration, duration)
    assert check_trajectory(q, t, LIMITS) is None
    q, t = one_joint_move(joint, -vmax * duration * LIFT, duration)
    refusal = check_trajectory(q, t, LIMITS)
    assert refusal.code == SafetyCode.JOINT_VELOCITY_LIMIT and refusal.check == "joint_velocity"
    assert refusal.message.startswith(
        f"segment via-point 0 → 1: {NAMES[joint]} velocity 1.5 rad/s exceeds its limit 1.5 rad/s"
    )


def test_velocity_names_worst_joint_of_first_fast_segment():
    q = np.repeat(Q0[None], 4, axis=0)
    q[1:, 0] += 0.1  # segment 0 → 1: J1 at 1 rad/s (fine)
    q[2:, 1] += 0.2  # segment 1 → 2: J2 at 2 rad/s ...
    q[2:, 2] += 0.25  # ... J3 at 2.5 rad/s (worst)
    q[3:, 3] += 0.4  # segment 2 → 3: J4 at 4 rad/s (later)
    t = np.array([0.0, 0.1, 0.2, 0.3])
    refusal = check_velocities(q, t, LIMITS)
    assert refusal.message.startswith(
        "segment via-point 1 → 2: wam_j3_joint velocity 2.5 rad/s exceeds its limit 1.5 rad/s"
    )
    assert "2 of 3 over, worst 2.667x" in refusal.message
    np.testing.assert_allclose(
        segment_velocities(q, t)[:, :4], [[1, 0, 0, 0], [0, 2, 2.5, 0], [0, 0, 0, 4]]
    )


# ------------------------------------------------------------------ acceleration
def test_acceleration_estimate_is_exact_for_constant_acceleration():
    q, t = bang_bang(4, 7.0)
    a = via_point_accelerations(q, t)[:, 4]
    n = len(t) // 2
    np.testing.assert_allclose(a[:n], 7.0, rtol=1e-9)  # accelerating, from rest at point 0
    np.testing.assert_allclose(a[n + 1 :], -7.0, rtol=1e-9)  # braking, to rest after the last
    np.testing.assert_allclose(np.delete(via_point_accelerations(q, t), 4, axis=1), 0.0)


@pytest.mark.parametrize("joint", range(7))
def test_acceleration_limit_boundary(joint):
    amax = LIMITS.max_acceleration[joint]
    q, t = bang_bang(joint, amax)
    assert np.abs(segment_velocities(q, t)).max() <= LIMITS.max_velocity[joint]
    assert check_trajectory(q, t, LIMITS) is None
    q, t = bang_bang(joint, amax * LIFT)
    refusal = check_trajectory(q, t, LIMITS)
    assert refusal.code == SafetyCode.JOINT_ACCELERATION_LIMIT
    assert refusal.check == "joint_acceleration"
    assert refusal.message.startswith(
        f"via-point 0: {NAMES[joint]} acceleration {amax:.4g} rad/s² exceeds its limit "
        f"{amax:.4g} rad/s²"
    )


def test_stop_at_the_end_counts_as_acceleration():
    # Cruising at 1.2 rad/s (within the velocity limit) with gentle starts, then one 0.01 s
    # segment to the end: braking from 1.2 rad/s to rest over 5 ms is 240 rad/s².
    q = np.repeat(Q0[None], 5, axis=0)
    q[:, 0] += [0.0, 0.18, 0.42, 0.66, 0.672]
    t = np.array([0.0, 0.3, 0.5, 0.7, 0.71])
    assert check_velocities(q, t, LIMITS) is None
    refusal = check_trajectory(q, t, LIMITS)
    assert refusal.code == SafetyCode.JOINT_ACCELERATION_LIMIT
    assert refusal.message.startswith("via-point 4: wam_j1_joint acceleration 240 rad/s²")


# ------------------------------------------------------------------ workspace
def test_workspace_box_boundary_and_point_names():
    p = workspace_points(Q0[None])[0]
    np.testing.assert_allclose(p[0], wam.fk(Q0)[:3, 3])
    np.testing.assert_allclose(p[1:], wam.arm_points(Q0))
    q, t = one_joint_move(0, 0.3, 2.0)  # J1 swings the arm towards +y
    pts = workspace_points(q)
    lo, hi = pts.reshape(-1, 3).min(axis=0), pts.reshape(-1, 3).max(axis=0)
    assert check_trajectory(q, t, with_box(lo, hi)) is None  # every extreme point on a face
    # The elbow (frame 4 origin) is the highest point: a ceiling 1 µm lower refuses it.
    assert np.argmax(pts[0, :, 2]) == 2
    top = hi.copy()
    top[2] -= 1e-6
    refusal = check_trajectory(q, t, with_box(lo, top))
    assert refusal.code == SafetyCode.WORKSPACE and refusal.check == "workspace"
    assert refusal.message.startswith(f"via-point 0: the {WORKSPACE_POINTS[2]} at (")
    assert f"0.000 m above the box's max z = {top[2]:.3f} m" in refusal.message
    assert "2 of 2 via-points outside" in refusal.message
    # The hand swings farthest to +y: a side face 1 mm inside its end position refuses it.
    side = hi.copy()
    side[1] = pts[1, 0, 1] - 1e-3
    refusal = check_workspace(q, with_box(lo, side))
    assert refusal.message.startswith(f"via-point 1: the {WORKSPACE_POINTS[0]} at (")
    assert f"0.001 m above the box's max y = {side[1]:.3f} m" in refusal.message


def test_hand_lowered_into_the_table_leaves_the_default_box():
    # Straight down from home to a hand frame origin 4 cm above the table top, slowly.
    T = np.repeat(wam.fk(Q0)[None], 21, axis=0)
    T[:, 2, 3] = np.linspace(0.55, 0.04, 21)
    q, ok = wam.ik_batch(T, Q0)
    assert ok.all()
    t = np.arange(21) * 1.0
    assert check_positions(q, LIMITS) is None and check_accelerations(q, t, LIMITS) is None
    refusal = check_trajectory(q, t, LIMITS)
    assert refusal.code == SafetyCode.WORKSPACE
    first = int(np.argmax(T[:, 2, 3] < LIMITS.workspace_min[2]))
    assert refusal.message.startswith(f"via-point {first}: the hand frame origin at (")
    assert "below the box's min z = 0.060 m" in refusal.message


def test_check_order_velocity_before_workspace():
    q, t = one_joint_move(0, 1.0, 0.1)  # 10 rad/s, and out of a tiny box
    refusal = check_trajectory(q, t, with_box([0.0, 0.0, 0.0], [0.1, 0.1, 0.1]))
    assert refusal.code == SafetyCode.JOINT_VELOCITY_LIMIT


# ------------------------------------------------------------------ speed scaling
def test_scale_time_caps_speed():
    np.testing.assert_allclose(scale_time([0.0, 1.0, 3.0], 0.5), [0.0, 2.0, 6.0])
    np.testing.assert_array_equal(scale_time(np.array([0.0, 0.2]), 1.0), [0.0, 0.2])
    for bad in (0.0, -0.5, 1.0001, float("nan"), float("inf"), True, "0.5"):
        with pytest.raises(ValueError, match="speed_scale"):
            scale_time([0.0, 1.0], bad)
    # Twice too fast and four times too hard: half speed passes both limits.
    q, t = bang_bang(0, 2 * LIMITS.max_acceleration[0] * (1 - 1e-6), half=0.05, h=0.01)
    assert check_accelerations(q, t, LIMITS) is not None
    assert check_trajectory(q, scale_time(t, 0.5), LIMITS) is None
    q, t = one_joint_move(2, 2 * 1.5 * 0.5, 0.5)
    assert check_velocities(q, t, LIMITS) is not None
    assert check_trajectory(q, scale_time(t, 0.5), LIMITS) is None


# ------------------------------------------------------------------ force ceiling
def test_force_ceiling():
    ceiling = ForceCeiling(20.0, 0.2)
    w = np.zeros((3, 6))
    assert ceiling.check(w) is None
    w[1, :3] = (0.0, 0.0, 20.0)  # exactly at the ceiling
    w[2, 3:] = (0.0, 0.2, 0.0)
    assert ceiling.check(w) is None
    w[1, :3] = (12.0, 12.0, 12.0)  # each axis under 20 N, the magnitude 20.8 N over
    refusal = ceiling.check(w)
    assert refusal == Refusal(
        SafetyCode.FORCE_LIMIT,
        "force_ceiling",
        "fingertip 2: force 20.8 N exceeds the ceiling 20 N",
    )
    w[0, 3:] = (0.3, 0.0, 0.0)  # fingertip 1 torque 1.5x its ceiling: the worst
    refusal = ceiling.check(w)
    assert refusal.message == "fingertip 1: torque 0.3 N m exceeds the ceiling 0.2 N m"
    w[2, 0] = np.nan
    assert ceiling.check(w).code == SafetyCode.SENSOR_FAULT
    assert "fingertip 3: non-finite" in ceiling.check(w).message
    with pytest.raises(ValueError, match="wrenches"):
        ceiling.check(np.zeros((3, 3)))
    for bad in ((0.0, 0.2), (20.0, -1.0), (float("nan"), 0.2)):
        with pytest.raises(ValueError):
            ForceCeiling(*bad)


# ------------------------------------------------------------------ watchdog
def test_watchdog_staleness():
    dog = Watchdog(0.1, ("joint_states", "fingertip1", "fingertip2"))
    assert dog.stale(0.0) == ["joint_states", "fingertip1", "fingertip2"]  # never fed
    dog.feed("fingertip2", 10.0)
    dog.feed("joint_states", 10.05)
    assert dog.stale(10.1) == ["fingertip1"]  # fingertip2 exactly 0.1 s old: still fresh
    assert dog.stale(10.1 + 1e-6) == ["fingertip1", "fingertip2"]
    dog.feed("fingertip1", 10.2)
    dog.feed("fingertip2", 10.2)
    assert dog.stale(10.2) == ["joint_states"]
    dog.feed("fingertip1", 9.0)  # an older sample does not make the stream older
    assert dog.age("fingertip1", 10.25) == pytest.approx(0.05)
    assert dog.age("joint_states", 10.25) == pytest.approx(0.2)
    assert Watchdog(0.1, ["a"]).age("a", 5.0) == np.inf
    with pytest.raises(KeyError, match="unknown stream"):
        dog.feed("fingertip3", 10.0)
    for bad in ((0.0, ["a"]), (0.1, []), (0.1, ["a", "a"]), (float("nan"), ["a"])):
        with pytest.raises(ValueError):
            Watchdog(*bad)


def test_watchdog_threads():
    streams = [f"s{i}" for i in range(8)]
    dog = Watchdog(0.5, streams)
    rng = np.random.default_rng(0)
    times = rng.uniform(0.0, 100.0, size=(8, 500))

    def feed(i: int) -> None:
        for s in times[i]:
            dog.feed(streams[i], float(s))
            dog.stale(float(s))

    threads = [threading.Thread(target=feed, args=(i,)) for i in range(8)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    newest = times.max(axis=1)
    for i, s in enumerate(streams):
        assert dog.age(s, 100.0) == pytest.approx(100.0 - newest[i])
    assert dog.stale(newest.min() + 0.5) == []  # the oldest stream exactly 0.5 s old
    assert dog.stale(newest.min() + 0.5 + 1e-6) == [streams[int(np.argmin(newest))]]


# ------------------------------------------------------------------ E-stop
def test_estop_starts_latched_not_armed_and_latches_until_reset_after_release():
    stop = EStop()
    assert stop.engaged and stop.reason == EStop.NOT_ARMED  # fail-safe: not armed at start
    assert stop.run_if_released(lambda: "sent") == (False, None)
    assert stop.reset() == (True, "E-stop released: commands are accepted again")
    assert not stop.engaged and stop.reason == ""
    assert stop.run_if_released(lambda: "sent") == (True, "sent")
    stop.on_message(False)
    assert not stop.engaged
    assert stop.on_message(True)  # latched just now
    assert stop.engaged and "said engaged" in stop.reason
    assert not stop.on_message(True)  # already latched
    ok, message = stop.reset()
    assert not ok and "still says engaged" in message and stop.engaged
    stop.on_message(False)  # released: still latched
    assert stop.engaged
    ok, _ = stop.reset()
    assert ok and not stop.engaged
    stop.on_message(True)
    stop.on_message(False)
    assert stop.engaged  # a short press latches too
    assert stop.reset()[0] and not stop.engaged


def test_estop_threads():
    stop = EStop()
    barrier = threading.Barrier(4)

    def press() -> None:
        barrier.wait()
        for _ in range(200):
            stop.on_message(True)
            stop.on_message(False)
            stop.reset()

    threads = [threading.Thread(target=press) for _ in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    stop.on_message(True)
    stop.on_message(False)
    assert stop.engaged and stop.reset()[0] and not stop.engaged


def race_a_latch(delay_s: float) -> list[str]:
    """Fifty commands through run_if_released on one thread and a latch after ``delay_s`` [s]
    on another; the log of both, in order."""
    stop = EStop()
    stop.reset()
    log: list[str] = []
    go = threading.Barrier(2)

    def commands() -> None:
        go.wait()
        for _ in range(50):
            stop.run_if_released(lambda: log.append("command"))

    def press() -> None:
        go.wait()
        time.sleep(delay_s)
        stop.on_message(True)
        log.append("latched")

    threads = [threading.Thread(target=commands), threading.Thread(target=press)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    return log


def test_no_command_runs_after_a_latch_that_races_it():
    """Latches at random instants against a stream of commands: none runs after the latch."""
    rng = np.random.default_rng(5)
    for trial in range(200):
        log = race_a_latch(float(rng.uniform(0.0, 2e-4)))
        assert "command" not in log[log.index("latched") :], f"trial {trial}: {log}"


def test_a_silent_heartbeat_latches_and_blocks_the_reset():
    stop = EStop(heartbeat_timeout_s=0.5, now_s=10.0)
    assert stop.reset(10.1)[0]
    stop.on_message(False, 10.3)
    assert not stop.check_heartbeat(10.7) and not stop.engaged  # 0.4 s since the last message
    assert stop.check_heartbeat(10.9) and stop.engaged  # 0.6 s: the deadman latches
    assert "no E-stop heartbeat" in stop.reason
    ok, message = stop.reset(11.0)
    assert not ok and "heartbeat" in message
    stop.on_message(False, 11.1)  # the publisher is back
    assert stop.reset(11.2)[0] and not stop.engaged
    assert not EStop(heartbeat_timeout_s=0.0).check_heartbeat(1e9)  # off


def test_a_heartbeat_that_stalled_with_the_bridge_has_a_timeout_to_return():
    """The host stalled 2.4 s (the bridge and the E-stop's publisher alike): the silence counts
    from when the bridge runs again, so the next beat, 50 ms later, comes in time; a publisher
    that stays silent still latches a timeout later."""
    stalled = EStop(heartbeat_timeout_s=0.3, now_s=0.0)
    assert stalled.reset(0.05)[0]
    stalled.on_message(False, 0.1)
    plain = EStop(heartbeat_timeout_s=0.3, now_s=0.0)
    assert plain.reset(0.05)[0]
    plain.on_message(False, 0.1)
    stalled.resumed(2.5)  # the watchdog's first tick after the stall
    assert plain.check_heartbeat(2.51)  # without it: 2.41 s of "silence" latch at once
    assert not stalled.check_heartbeat(2.51) and not stalled.engaged
    stalled.on_message(False, 2.55)  # the publisher's next beat
    assert not stalled.check_heartbeat(2.8) and not stalled.engaged
    assert stalled.check_heartbeat(2.9) and "0.35 s" in stalled.reason  # silent since 2.55


def test_a_latch_survives_a_restart_through_its_file(tmp_path):
    path = tmp_path / "estop.latched"
    first = EStop(latch_file=path)
    first.reset()
    assert not path.exists()
    first.on_message(True)
    assert path.exists() and "said engaged" in path.read_text()
    second = EStop(latch_file=path)  # the bridge restarted
    assert second.engaged and second.reason.startswith("latched before this start")
    second.on_message(False)
    assert second.reset()[0] and not path.exists()
    third = EStop(latch_file=path)
    assert third.reason == EStop.NOT_ARMED  # a clean start is only "not armed"


# ------------------------------------------------------------------ the executor's moves
REALISM_OBJECTS = ("powerdrill", "cup")


@pytest.fixture(scope="module")
def executor_moves():
    """Every via-point trajectory (object, WRT, phase, q, t) the executor sends to
    PhysicsWorld.follow while running every WRT of REALISM_OBJECTS at the nominal pose and
    retreating from it."""
    from rrg_models.objects import get_object
    from rrg_sim.physics.world import PhysicsWorld

    moves, where = [], {}
    original = PhysicsWorld.follow

    def recording(self, q, t, *args, **kwargs):
        moves.append((*where.values(), np.array(q, float), np.array(t, float)))
        return original(self, q, t, *args, **kwargs)

    e = np.asarray(WORLD.nominal_pose, dtype=float)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(PhysicsWorld, "follow", recording)
        for name in REALISM_OBJECTS:
            world = PhysicsWorld(name, seed=0)
            for wrt in get_object(name).wrts():
                where.update(obj=name, wrt=wrt.name, phase="execute")
                world.execute_wrt(wrt, e)
                where["phase"] = "retreat"
                world.retreat()
    return moves


def _without_repeats(q: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop via-points repeating their predecessor (same time and configuration), as the
    bridge does before checking (rrg_hw_bridge.ros.bridge_node: plan)."""
    keep = np.r_[True, np.diff(t) > 0]
    return q[keep], t[keep]


def test_executor_moves_fit_positions_and_workspace(executor_moves):
    from rrg_models.objects import get_object

    wrts = {(m[0], m[1], m[2]) for m in executor_moves}
    for name in REALISM_OBJECTS:
        for wrt in get_object(name).wrts():
            assert {(name, wrt.name, "execute"), (name, wrt.name, "retreat")} <= wrts
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for obj, wrt, phase, q, t in executor_moves:
        # The only non-increasing times are exact repeats of a via-point (the end of some
        # retreats), which the bridge drops.
        dt = np.diff(t)
        assert (np.abs(np.diff(q, axis=0))[dt <= 0] < 1e-12).all(), (obj, wrt, phase)
        q, t = _without_repeats(q, t)
        assert check_shape(q, t, LIMITS) is None, (obj, wrt, phase)
        assert check_positions(q, LIMITS) is None, (obj, wrt, phase)
        assert check_workspace(q, LIMITS) is None, (obj, wrt, phase)
        p = workspace_points(q).reshape(-1, 3)
        lo, hi = np.minimum(lo, p.min(axis=0)), np.maximum(hi, p.max(axis=0))
    # The margins the limits file states (workspace.source.z_min).
    margin_lo, margin_hi = lo - LIMITS.workspace_min, LIMITS.workspace_max - hi
    assert margin_lo[2] >= 0.025
    assert min(margin_lo.min(), margin_hi.min()) >= 0.025


def test_executor_moves_velocity_and_acceleration(executor_moves):
    v_ratio, a_ratio = np.zeros(7), np.zeros(7)
    for obj, wrt, phase, q, t in executor_moves:
        q, t = _without_repeats(q, t)
        v = np.abs(segment_velocities(q, t)).max(axis=0) / LIMITS.max_velocity
        a = np.abs(via_point_accelerations(q, t)).max(axis=0) / LIMITS.max_acceleration
        v_ratio, a_ratio = np.maximum(v_ratio, v), np.maximum(a_ratio, a)
        # The checks refuse exactly the moves the measurement says exceed a limit.
        refused_v = check_velocities(q, t, LIMITS)
        assert (refused_v is not None) == bool((v > 1 + RATE_REL_TOL).any()), (obj, wrt, phase)
        refused_a = check_accelerations(q, t, LIMITS)
        assert (refused_a is not None) == bool((a > 1 + RATE_REL_TOL).any()), (obj, wrt, phase)
    # J1-J4 run at most at Barrett's 1.5 rad/s (the executor's own joint speed limit there).
    assert (v_ratio[:4] <= 1 + RATE_REL_TOL).all(), v_ratio


def test_slowdown_to_limits_is_the_smallest_stretch_that_passes():
    from rrg_hw_bridge.arm_limits import load_arm_limits
    from rrg_hw_bridge.safety import check_trajectory, slowdown_to_limits
    from rrg_models.wam import HOME_Q

    limits = load_arm_limits()
    q = np.tile(HOME_Q, (3, 1))
    q[:, 6] += [0.0, 0.3, 0.6]  # J7 through 0.6 rad
    t = np.array([0.0, 0.1, 0.2])  # 3 rad/s: twice the 1.5 rad/s limit
    k = slowdown_to_limits(q, t, limits)
    assert k > 1.0
    assert check_trajectory(q, t * k * 1.000001, limits) is None
    assert check_trajectory(q, t * k * 0.99, limits) is not None
    slow = np.array([0.0, 2.0, 4.0])
    assert slowdown_to_limits(q, slow, limits) == 1.0
