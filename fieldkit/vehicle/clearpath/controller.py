"""The Husky's go-to-point controller: where it is, where it faces, where to go -> wheel speeds.

    ctl = GotoController(max_speed_mps=1.0, max_accel_mps2=3.0, accuracy_m=0.5,
                         wheel_separation_m=1.07, max_turn_rate_rps=2.0)
    left, right = ctl.step(distance_m, bearing_rad, heading_rad, dt=0.1)
    ctl.arrived                          # stopped inside the accuracy radius

A differential base cannot move sideways, so the controller turns toward the target and
drives: the forward speed is the largest from which it can still brake to a stop at the
target (v = sqrt(2 a' d) with a' = 80 % of the profile's acceleration, leaving room for the
MCU's ramp), capped at the profile's speed, scaled by cos(heading error) and zero while the
error is above 60 degrees (it turns in place first); the turn rate is proportional to the
error, within `max_turn_rate_rps`. The forward speed changes by at most `max_accel x dt`
per step, and both wheel speeds stay within the profile's speed (scaled together, keeping
the turn radius, as husky_base does), so the base never exceeds the profile's limits.

Arrival: within half the accuracy radius it stops and latches `arrived`; it starts again
only if it ends up farther than the whole radius (GPS noise does not make it dance). With no
heading known yet (no IMU, never moved) it drives straight ahead at a third of its top speed
until the GPS track gives one. Angles are NED: 0 north, clockwise positive.
"""

from __future__ import annotations

import math

from fieldkit.vehicle.diffdrive import wheel_speeds

#: Above this heading error the base turns in place before driving.
TURN_IN_PLACE_RAD = math.radians(60.0)
#: Turn rate per radian of heading error, 1/s.
TURN_GAIN = 1.5
#: Share of the profile's acceleration the braking curve plans with.
BRAKE_SHARE = 0.8


class GotoController:
    """Turn toward a target and drive there within the speed, acceleration and turn limits."""

    def __init__(
        self,
        *,
        max_speed_mps: float,
        max_accel_mps2: float,
        accuracy_m: float,
        wheel_separation_m: float,
        max_turn_rate_rps: float,
    ) -> None:
        """A controller at rest."""
        self.max_speed = max_speed_mps
        self.max_accel = max_accel_mps2
        self.accuracy = accuracy_m
        self.separation = wheel_separation_m
        self.max_turn = max_turn_rate_rps
        self.speed = 0.0  # the forward speed it asked for last, m/s
        self.turn = 0.0  # the turn rate it asked for last, rad/s (NED: clockwise)
        self.arrived = False

    def reset(self) -> None:
        """A new target: not arrived; the speed ramp goes on from where it is."""
        self.arrived = False

    def stop(self) -> tuple[float, float]:
        """Zero wheel speeds (the MCU brakes at its acceleration)."""
        self.speed = 0.0
        self.turn = 0.0
        return 0.0, 0.0

    def step(
        self, distance_m: float, bearing_rad: float, heading_rad: float | None, dt: float
    ) -> tuple[float, float]:
        """(left, right) wheel speeds, m/s, for a target `distance_m` away at `bearing_rad`."""
        if not (math.isfinite(distance_m) and math.isfinite(bearing_rad)):
            return self.stop()
        if self.arrived and distance_m <= self.accuracy:
            return self.stop()
        if distance_m <= 0.5 * self.accuracy:
            self.arrived = True
            return self.stop()
        self.arrived = False
        brake = math.sqrt(2.0 * BRAKE_SHARE * self.max_accel * distance_m)
        want = min(self.max_speed, brake)
        if heading_rad is None or not math.isfinite(heading_rad):
            want = min(want, self.max_speed / 3.0)
            turn = 0.0
        else:
            err = math.remainder(bearing_rad - heading_rad, 2.0 * math.pi)
            want = 0.0 if abs(err) > TURN_IN_PLACE_RAD else want * math.cos(err)
            turn = max(-self.max_turn, min(self.max_turn, TURN_GAIN * err))
        step = self.max_accel * dt
        speed = self.speed + max(-step, min(step, want - self.speed))
        self.speed, self.turn = speed, turn
        # NED turn rate (clockwise) to the wheel relation's counter-clockwise omega.
        return wheel_speeds(speed, -turn, self.separation, self.max_speed)


__all__ = ["GotoController"]
