"""CARLA's default Leaderboard car, ``vehicle.lincoln.mkz_2020``, as a physics model.

CARLA (0.9.x, Unreal Engine 4 with PhysX vehicles) drives its cars with an engine, a clutch,
an automatic gearbox, brakes, drag and tyres. The ego's trajectories inherit their
imperfection from that machinery: a gear shift cuts the drive for half a second, the engine
brakes hard off the throttle in a low gear, the steering wheel turns at a finite rate. This
module models that machinery, integrated at 20 Hz in fixed sub-steps. The kinematic bicycle
of PDM-Lite (controller.vehicle) is the other ego model (``--vehicle kinematic``).

The functions of one tick run compiled (numba); compiled, they give the doubles this same
source gives run by CPython, bit for bit (docs/vehicle.md has their cost).

State
-----
Pose x, y [m] and yaw [rad] in the SUMO world frame (x east, y north, yaw counter-clockwise
from +x) of the centre of mass; body-frame velocity vx (forward), vy (left) [m/s]; yaw
rate r [rad/s]; engine speed w_e [rad/s]; the gear (1..5) and the shift in progress; the
applied steer, throttle and brake (after CARLA's input rates).

One tick (DT = 0.05 s) = the inputs, then SUBSTEPS semi-implicit Euler sub-steps of h = DT/SUBSTEPS
(the velocities first, then the pose moved with the new velocities).

1. Inputs (CARLA's actuators). The command moves towards the request at a limited rate
   (Unreal's vehicle input rates): away from 0 at RISE, back towards 0 at FALL [1/s]::

       u += clip(u_cmd - u, -rate h', rate h'),   rate = RISE if |u_cmd| > |u| else FALL

   Seeded Gaussian noise on steer and throttle (STEER_NOISE, THROTTLE_NOISE) is actuator
   imperfection, as in the kinematic model; a throttle commanded to 0 stays 0.

2. Gearbox (PhysX autobox). G = GEAR_RATIOS[g] * FINAL_RATIO. With no shift under way and
   AUTOBOX_LATENCY s since the last one::

       rpm_e > UP_RATIO * MAX_RPM and g < 5  ->  shift up
       rpm_e < DOWN_RATIO * MAX_RPM and g > 1  ->  shift down

   A shift puts the box in neutral (G = 0: no drive, no engine braking) for GEAR_SWITCH_TIME.

3. Engine and clutch (PhysX drive model; wheels roll without longitudinal slip, w_w = vx/R)::

       T_c   = CLUTCH_STRENGTH (w_e - G w_w)                      clutch torque (0 in neutral)
       d     = d_0 + (DAMP_FULL - d_0) throttle,  d_0 = DAMP_ZERO_ENGAGED (in gear) or
               DAMP_ZERO_DISENGAGED (neutral)
       I_e dw_e/dt = throttle T(rpm_e) - d w_e - T_c               T: TORQUE_CURVE, 0 above MAX_RPM

4. Longitudinal force on the car [N]::

       F_drive = G T_c / R
       F_brake = brake * 4 MAX_BRAKE_TORQUE / R                   (brake continuous in [0, 1])
       F_roll  = 4 WHEEL_DAMPING w_w / R                          (wheel bearing damping)
       F_drag  = 1/2 AIR_DENSITY DRAG_COEFFICIENT DRAG_AREA vx^2
       m dvx/dt = F_drive - F_brake - F_roll - F_drag - w F_yf sin(delta) + w m vy r   (w: the blend of 5)
       vx >= 0 (no reverse); at rest, the resisting forces hold the car unless F_drive beats them.

5. Lateral: a dynamic single-track (bicycle) model with linear tyres, blended into the
   kinematic one at low speed (the dynamic one is singular as vx -> 0)::

       delta   = -steer MAX_STEER_ANGLE curve(|v| in km/h)         front wheel angle (steer > 0 = right)
       alpha_f = delta - atan2(vy + LF r, vx),  alpha_r = -atan2(vy - LR r, vx)
       F_yf    = clip(C_f alpha_f, -mu Fz_f, mu Fz_f),   C_f = LAT_STIFF_VALUE / LAT_STIFF_MAX_LOAD * Fz_f
       F_yr    = clip(C_r alpha_r, -mu Fz_r, mu Fz_r),   Fz_f = m g LR / L, Fz_r = m g LF / L
       m dvy/dt  = F_yf cos(delta) + F_yr - m vx r
       I_z dr/dt = LF F_yf cos(delta) - LR F_yr
       kinematic:  r_k = vx tan(delta) / L,  vy_k = LR r_k
       blend:      w = clip((vx - V_KINEMATIC) / (V_DYNAMIC - V_KINEMATIC), 0, 1)
                   (vy, r) = w (vy, r)_dynamic + (1 - w) (vy_k, r_k)

6. Pose: x += (vx cos yaw - vy sin yaw) h,  y += (vx sin yaw + vy cos yaw) h,  yaw += r h.

The state's speed is |(vx, vy)|.

Parameters and where they come from
-----------------------------------
CARLA keeps each car's physics in its Unreal asset; ``vehicle.get_physics_control()``
prints them. No public printout of ``vehicle.lincoln.mkz_2020``'s was found, so the values
are those printed for CARLA's Lincoln MKZ 2017 (the Leaderboard 1.0 ego; the same PhysX
defaults), and where that printout lacks one, the nearest documented CARLA car's or CARLA's
API defaults, as marked (docs/vehicle.md has the table):

- [mkz17]  a Leaderboard-derived runner that re-applies "the Vehicle Physics Control the
           same as the setting in CARLA 0.9.10" to vehicle.lincoln.mkz_2017: torque curve
           (0, 400), (1890, 500), (5730, 400) Nm, max_rpm 5800, damping_rate_full_throttle
           0.15, gear_switch_time 0.5 s, final_ratio 4, mass 2404 kg, tyres tire_friction
           3.5, radius 35.5 cm, max_brake_torque 1500 Nm, max_steer_angle 70 deg, wheel
           positions (front axle x = -1855.75 cm, rear x = -2142.86 cm: wheelbase 2.871 m);
           the same mass, max_rpm, damping rates (0.15, 2.0, 0.35), gear_switch_time,
           clutch_strength 10 and drag_coefficient 0.3 are the default point of a CARLA
           physics fuzzer for the Leaderboard ego.
- [print]  a CARLA 0.9.x printout of get_physics_control() for its 4-wheel cars: torque
           curve (0, 400), (1890.76, 500), (5729.58, 400) Nm, moi 1.0, damping rates
           0.15 / 2.0 / 0.35, clutch_strength 10, steering_curve (0, 1), (20, 0.9),
           (60, 0.8), (120, 0.7).
- [gears]  the one public printout with forward_gears, of a smaller CARLA car (nearest
           documented): ratios 3.73, 2.05, 1.39, 1.03, 0.82, down_ratio 0.2, up_ratio 0.35.
- [api]    carla.WheelPhysicsControl defaults (LibCarla rpc/WheelPhysicsControl.h):
           damping_rate 0.25, lat_stiff_max_load 2.0, lat_stiff_value 17.0.
- [ue4]    Unreal Engine 4's wheeled-vehicle defaults, which CARLA does not expose:
           input rates (throttle and brake rise 6 / fall 10 per s, steering rise 2.5 / fall
           5 per s), autobox latency, chassis drag area 1.8 m x 1.4 m, air density 1.25.
- [approx] not a CARLA parameter: the centre of mass mid-wheelbase, I_z = m LF LR, wheels
           without longitudinal slip, C = LAT_STIFF_VALUE / LAT_STIFF_MAX_LOAD * Fz
           (PhysX's lateral stiffness at the rest load, linear below the max load).
"""
from __future__ import annotations

import math

import numba
import numpy as np

from controller.hypot import hypot
from controller.vehicle import DT, Control, EgoState

SUBSTEPS = 5  # integration sub-steps per 0.05 s tick (h = 0.01 s)
G = 9.81  # gravity [m/s^2]

# engine [mkz17], [print]
TORQUE_CURVE = ((0.0, 400.0), (1890.76, 500.0), (5729.58, 400.0))  # (rpm, Nm); held flat to MAX_RPM
MAX_RPM = 5800.0  # [rpm]
ENGINE_MOI = 1.0  # [kg m^2]
DAMP_FULL = 0.15  # engine damping at full throttle [N m s/rad]
DAMP_ZERO_ENGAGED = 2.0  # ... at zero throttle, clutch engaged
DAMP_ZERO_DISENGAGED = 0.35  # ... at zero throttle, clutch disengaged (neutral)
CLUTCH_STRENGTH = 10.0  # [N m s/rad]
# gearbox [mkz17] (switch time, final ratio), [gears] (ratios, shift points), [ue4] (latency)
GEAR_RATIOS = (3.73, 2.05, 1.39, 1.03, 0.82)
FINAL_RATIO = 4.0
UP_RATIO, DOWN_RATIO = 0.35, 0.2  # shift up above / down below this fraction of MAX_RPM
GEAR_SWITCH_TIME = 0.5  # [s] in neutral during a shift
AUTOBOX_LATENCY = 1.0  # [s] minimum time between two shifts
# body and wheels [mkz17], [api]
MASS = 2404.0  # [kg]
WHEELBASE = 2.871  # [m]
LF = LR = WHEELBASE / 2  # centre of mass to front / rear axle [m] [approx]
YAW_INERTIA = MASS * LF * LR  # [kg m^2] [approx]
WHEEL_RADIUS = 0.355  # [m]
MAX_BRAKE_TORQUE = 1500.0  # per wheel [N m]
WHEEL_DAMPING = 0.25  # per wheel [N m s/rad]
TIRE_FRICTION = 3.5  # friction coefficient of the tyres [-]
LAT_STIFF_MAX_LOAD, LAT_STIFF_VALUE = 2.0, 17.0  # PhysX lateral stiffness [-], [1/rad]
DRAG_COEFFICIENT = 0.3
DRAG_AREA = 1.8 * 1.4  # [m^2] [ue4]
AIR_DENSITY = 1.25  # [kg/m^3] [ue4]
# steering [mkz17], [print]
MAX_STEER_ANGLE = math.radians(70.0)  # front wheels at full lock, standstill [rad]
STEERING_CURVE = ((0.0, 1.0), (20.0, 0.9), (60.0, 0.8), (120.0, 0.7))  # (km/h, share of MAX_STEER_ANGLE)
# input rates [1/s] [ue4]: (rise away from 0, fall towards 0)
STEER_RATE, THROTTLE_RATE, BRAKE_RATE = (2.5, 5.0), (6.0, 10.0), (6.0, 10.0)
# low-speed blend of the lateral model [m/s]
V_KINEMATIC, V_DYNAMIC = 3.0, 6.0
# actuator noise per tick, as the kinematic model's (controller.vehicle)
STEER_NOISE, THROTTLE_NOISE = 0.01, 0.02

RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)
_FZ_F, _FZ_R = MASS * G * LR / WHEELBASE, MASS * G * LF / WHEELBASE  # axle loads [N]
C_FRONT = LAT_STIFF_VALUE / LAT_STIFF_MAX_LOAD * _FZ_F  # cornering stiffness of the axle [N/rad]
C_REAR = LAT_STIFF_VALUE / LAT_STIFF_MAX_LOAD * _FZ_R


# The state one tick advances, one float64 vector ``st`` (the names of the docstring's State,
# then the applied inputs): the sub-steps below are compiled (numba) and work on it in place.
X, Y, YAW, VX, VY, YAW_RATE, W_E, GEAR, SHIFT_LEFT, SINCE_SHIFT, STEER, THROTTLE, BRAKE = range(13)
STATE_SIZE = BRAKE + 1

# The functions below are compiled by numba and equal, bit for bit, to the same source run by
# CPython (tests/test_carla_car.py runs both): the same operations on the same doubles in the
# same order, libm's trigonometry in both, and CPython's own hypot (controller.hypot).
_jit = numba.njit(cache=True, error_model="numpy")


@_jit
def _interp(table: tuple, x: float) -> float:
    """Piecewise-linear y(x) of ((x, y), ...), held constant outside."""
    if x <= table[0][0]:
        return table[0][1]
    for i in range(1, len(table)):
        x0, y0 = table[i - 1]
        x1, y1 = table[i]
        if x <= x1:
            return y0 + (y1 - y0) * (x - x0) / (x1 - x0)
    return table[-1][1]


@_jit
def engine_torque(rpm: float) -> float:
    """Full-throttle engine torque [N m] at engine speed rpm; 0 above MAX_RPM."""
    return _interp(TORQUE_CURVE, rpm) if rpm <= MAX_RPM else 0.0


@_jit
def max_steer(speed: float) -> float:
    """Front wheel angle at full steer [rad] at speed [m/s] (CARLA's steering curve)."""
    return MAX_STEER_ANGLE * _interp(STEERING_CURVE, speed * 3.6)


@_jit
def _rate(u: float, cmd: float, rise: float, fall: float, dt: float) -> float:
    """1. Input u moved towards cmd at most rate * dt (rise away from 0, fall towards 0)."""
    step = (rise if abs(cmd) > abs(u) else fall) * dt
    return u + min(max(cmd - u, -step), step)


@_jit
def _ratio(st: np.ndarray) -> float:
    """Total ratio engine : wheels now (0 while a shift is under way)."""
    return 0.0 if st[SHIFT_LEFT] > 0.0 else GEAR_RATIOS[int(st[GEAR]) - 1] * FINAL_RATIO


@_jit
def _gearbox(st: np.ndarray, h: float) -> None:
    """2. The autobox: start, or finish, a shift."""
    if st[SHIFT_LEFT] > 0.0:
        st[SHIFT_LEFT] = max(st[SHIFT_LEFT] - h, 0.0)
        return
    st[SINCE_SHIFT] += h
    if st[SINCE_SHIFT] < AUTOBOX_LATENCY:
        return
    rpm = st[W_E] * RPM_PER_RAD_S
    if rpm > UP_RATIO * MAX_RPM and st[GEAR] < len(GEAR_RATIOS):
        st[GEAR] += 1.0
    elif rpm < DOWN_RATIO * MAX_RPM and st[GEAR] > 1.0:
        st[GEAR] -= 1.0
    else:
        return
    st[SHIFT_LEFT], st[SINCE_SHIFT] = GEAR_SWITCH_TIME, 0.0


@_jit
def _engine(st: np.ndarray, h: float) -> float:
    """3. Engine speed after h; returns the drive force on the car [N]."""
    g = _ratio(st)
    w_e, throttle = st[W_E], st[THROTTLE]
    t_clutch = CLUTCH_STRENGTH * (w_e - g * st[VX] / WHEEL_RADIUS) if g > 0.0 else 0.0
    d0 = DAMP_ZERO_ENGAGED if g > 0.0 else DAMP_ZERO_DISENGAGED
    damping = d0 + (DAMP_FULL - d0) * throttle
    torque = throttle * engine_torque(w_e * RPM_PER_RAD_S)
    st[W_E] = max(w_e + (torque - damping * w_e - t_clutch) / ENGINE_MOI * h, 0.0)
    return g * t_clutch / WHEEL_RADIUS


@_jit
def _tyres(st: np.ndarray, delta: float) -> tuple[float, float, float]:
    """5. Front lateral force [N] and the dynamic model's dvy/dt, dr/dt."""
    vy, r = st[VY], st[YAW_RATE]
    vx = max(st[VX], V_KINEMATIC)  # below it the dynamic terms are not used (w = 0)
    alpha_f = delta - math.atan2(vy + LF * r, vx)
    alpha_r = -math.atan2(vy - LR * r, vx)
    f_yf = min(max(C_FRONT * alpha_f, -TIRE_FRICTION * _FZ_F), TIRE_FRICTION * _FZ_F)
    f_yr = min(max(C_REAR * alpha_r, -TIRE_FRICTION * _FZ_R), TIRE_FRICTION * _FZ_R)
    cd = math.cos(delta)
    dvy = (f_yf * cd + f_yr) / MASS - st[VX] * r
    dr = (LF * f_yf * cd - LR * f_yr) / YAW_INERTIA
    return f_yf, dvy, dr


@_jit
def _dynamic_share(vx: float) -> float:
    """The dynamic lateral model's weight in the blend at forward speed vx [m/s]."""
    return min(max((vx - V_KINEMATIC) / (V_DYNAMIC - V_KINEMATIC), 0.0), 1.0)


@_jit
def _longitudinal(st: np.ndarray, h: float, f_drive: float, f_cornering: float) -> None:
    """4. Forward speed after h (no reverse; held at rest by the resisting forces)."""
    vx = st[VX]
    w = _dynamic_share(vx)
    f_resist = (st[BRAKE] * 4 * MAX_BRAKE_TORQUE / WHEEL_RADIUS
                + 4 * WHEEL_DAMPING * vx / WHEEL_RADIUS ** 2
                + 0.5 * AIR_DENSITY * DRAG_COEFFICIENT * DRAG_AREA * vx * vx)
    if vx <= 0.0 and f_drive <= f_resist:
        st[VX] = 0.0
        return
    a = (f_drive - f_resist - w * f_cornering) / MASS + w * st[VY] * st[YAW_RATE]
    st[VX] = max(vx + a * h, 0.0)


@_jit
def _lateral(st: np.ndarray, h: float, delta: float, dvy: float, dr: float) -> None:
    """5. vy and r after h: the dynamic model blended with the kinematic one."""
    w = _dynamic_share(st[VX])
    r_k = st[VX] * math.tan(delta) / WHEELBASE
    st[VY] = w * (st[VY] + dvy * h) + (1.0 - w) * LR * r_k
    st[YAW_RATE] = w * (st[YAW_RATE] + dr * h) + (1.0 - w) * r_k


@_jit
def _substep(st: np.ndarray, h: float) -> None:
    """One semi-implicit Euler sub-step of h [s]: 2 to 6 of the docstring."""
    _gearbox(st, h)
    f_drive = _engine(st, h)
    delta = -st[STEER] * max_steer(hypot(st[VX], st[VY]))
    f_yf, dvy, dr = _tyres(st, delta)
    _longitudinal(st, h, f_drive, f_yf * math.sin(delta))
    _lateral(st, h, delta, dvy, dr)
    cy, sy = math.cos(st[YAW]), math.sin(st[YAW])
    st[X] += (st[VX] * cy - st[VY] * sy) * h
    st[Y] += (st[VX] * sy + st[VY] * cy) * h
    st[YAW] = (st[YAW] + st[YAW_RATE] * h + math.pi) % (2 * math.pi) - math.pi


# an explicit signature: compiled (or loaded from numba's cache) when this module is imported
@numba.njit(numba.types.UniTuple(numba.float64, 4)(numba.float64[:], numba.float64, numba.float64,
                                                   numba.float64, numba.float64),
            cache=True, error_model="numpy")
def _tick(st: np.ndarray, steer_cmd: float, throttle_cmd: float, brake_cmd: float,
          dt: float) -> tuple[float, float, float, float]:
    """One tick of dt [s] from the commanded inputs (noise already drawn): 1, then SUBSTEPS
    sub-steps; returns the pose and speed (x, y, yaw, |(vx, vy)|)."""
    st[STEER] = min(max(_rate(st[STEER], steer_cmd, STEER_RATE[0], STEER_RATE[1], dt), -1.0), 1.0)
    st[THROTTLE] = _rate(st[THROTTLE], throttle_cmd, THROTTLE_RATE[0], THROTTLE_RATE[1], dt)
    st[BRAKE] = _rate(st[BRAKE], brake_cmd, BRAKE_RATE[0], BRAKE_RATE[1], dt)
    h = dt / SUBSTEPS
    for _ in range(SUBSTEPS):
        _substep(st, h)
    return st[X], st[Y], st[YAW], hypot(st[VX], st[VY])


def _field(i: int, kind: type = float) -> property:
    """The state vector's entry i as an attribute of the car, read as ``kind``, written as a double."""
    def get(self: "CarlaCar") -> float | int:
        return kind(self.st[i])

    def put(self: "CarlaCar", value: float) -> None:
        self.st[i] = value
    return property(get, put)


class CarlaCar:
    """The ego as CARLA's Lincoln MKZ: ``step(control) -> EgoState``, as
    controller.vehicle.EgoVehicle. ``noise``: the seeded steer and throttle noise."""

    x, y, yaw = _field(X), _field(Y), _field(YAW)  # pose [m], [m], [rad]
    vx, vy, r = _field(VX), _field(VY), _field(YAW_RATE)  # body-frame velocity [m/s], yaw rate [rad/s]
    w_e, gear = _field(W_E), _field(GEAR, int)  # engine speed [rad/s], gear 1..5
    shift_left = _field(SHIFT_LEFT)  # [s] of neutral left in the shift under way
    since_shift = _field(SINCE_SHIFT)  # [s] since the last shift
    steer, throttle, brake = _field(STEER), _field(THROTTLE), _field(BRAKE)  # the applied inputs

    def __init__(self, start: EgoState, rng: np.random.Generator, noise: bool = True):
        self.rng, self.noise = rng, noise
        self.st = np.zeros(STATE_SIZE)
        self.x, self.y, self.yaw = start.x, start.y, start.yaw
        self.vx, self.vy, self.r = start.v, 0.0, 0.0
        self.gear = 1
        self.w_e = start.v / WHEEL_RADIUS * GEAR_RATIOS[0] * FINAL_RATIO  # engine turning with the wheels
        self.shift_left = 0.0
        self.since_shift = AUTOBOX_LATENCY
        self.steer = self.throttle = self.brake = 0.0
        self.state = start

    def step(self, control: Control, dt: float = DT) -> EgoState:
        """Apply one control for dt seconds; returns the new state."""
        c = control.clipped()
        steer_cmd, throttle_cmd = c.steer, c.throttle
        if self.noise:  # a throttle commanded off stays off (the draw is made all the same)
            steer_cmd += float(self.rng.normal(0.0, STEER_NOISE))
            noisy = min(max(throttle_cmd + float(self.rng.normal(0.0, THROTTLE_NOISE)), 0.0), 1.0)
            throttle_cmd = noisy if throttle_cmd > 0.0 else 0.0
        self.state = EgoState(*_tick(self.st, steer_cmd, throttle_cmd, c.brake, dt))
        return self.state

    def ratio(self) -> float:
        """Total ratio engine : wheels now (0 while a shift is under way)."""
        return _ratio(self.st)

    def _gearbox(self, h: float) -> None:
        """2. The autobox alone, for h [s] (the tests' hand-checked shifts)."""
        _gearbox(self.st, h)
