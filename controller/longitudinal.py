"""PDM-Lite's longitudinal controller: a fitted linear regression from (speed, speed error)
to throttle, close to bang-bang, with a binary brake (docs/design.md §8.3).

Works in km/h inside, as fitted:
1. target < 1e-5 m/s or a hazard brake -> throttle 0, brake;
2. targets below 1 km/h are raised to 1 km/h;
3. error e = target - v > 1.89 km/h -> full throttle;
4. v / target > 1.0313 -> brake;
5. else throttle = clip(p0 v' + p1 v'^2 + p2 (100 e') + p3 e'^2 + p4 v' e' + p5 v'^2 e', 0, 1)
   with v' = v/100, e' = max(e, 0)/100.
"""
from __future__ import annotations

P = (1.1990342347353184, -0.8057602384167799, 1.710818710950062, 0.921890257450335,
     1.556497522998393, -0.7013479734904027)
BRAKE_RATIO = 1.031266635497984  # speed / target above which it brakes
FULL_THROTTLE_ERROR = 1.89  # [km/h] speed error above which it gives full throttle
MIN_TARGET = 0.278  # [m/s] = 1 km/h


def throttle_brake(target: float, speed: float, hazard_brake: bool = False) -> tuple[float, float]:
    """(throttle, brake) for a target speed and the current speed [m/s]."""
    if target < 1e-5 or hazard_brake:
        return 0.0, 1.0
    target = max(target, MIN_TARGET)
    t_kmh, v_kmh = target * 3.6, speed * 3.6
    e = t_kmh - v_kmh
    if e > FULL_THROTTLE_ERROR:
        return 1.0, 0.0
    if v_kmh / t_kmh > BRAKE_RATIO:
        return 0.0, 1.0
    v, ep = v_kmh / 100.0, max(e, 0.0) / 100.0
    th = P[0] * v + P[1] * v * v + P[2] * 100 * ep + P[3] * ep * ep + P[4] * v * ep + P[5] * v * v * ep
    return min(max(th, 0.0), 1.0), 0.0
