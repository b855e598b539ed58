"""A differential (skid-steer) base: two wheel speeds in, a pose out, stepped at a fixed dt.

    base = DiffDrive(wheel_separation_m=1.07, max_speed_mps=1.0)
    base.command(0.5, 0.3, accel=3.0)      # left, right wheel speeds (m/s), ramped at accel
    base.step(0.02)                        # no wall clock
    base.x, base.y, base.yaw               # ENU metres; yaw 0 east, counter-clockwise
    base.travel                            # (left, right) cumulative wheel travel, metres

The shared model of a wheeled robot driven wheel by wheel: the simulated Clearpath MCU moves
with it, and the Husky core's go-to controller plans with the same relations (v = (v_R +
v_L) / 2, omega = (v_R - v_L) / B, spec section 9). Each wheel's speed moves toward its
command by at most `accel x dt` per step and stays within +-`max_speed_mps`, as the MCU's own
limits do. The pose is integrated along the arc of each step (exact for constant wheel speeds),
so a step size does not bend a straight line or a turn in place. Plain float arithmetic in a
fixed order: the same commands give the same poses.
"""

from __future__ import annotations

import math


def _toward(value: float, target: float, step: float) -> float:
    """`value` moved toward `target` by at most `step`."""
    if target > value + step:
        return value + step
    if target < value - step:
        return value - step
    return target


class DiffDrive:
    """One differential base: wheel speeds ramp toward commands, the pose follows."""

    def __init__(
        self,
        *,
        wheel_separation_m: float,
        max_speed_mps: float,
        x: float = 0.0,
        y: float = 0.0,
        yaw: float = 0.0,
    ) -> None:
        """A base standing at (x, y) facing `yaw` (ENU radians: 0 east, counter-clockwise)."""
        if not (wheel_separation_m > 0 and max_speed_mps > 0):
            raise ValueError("wheel_separation_m and max_speed_mps must be > 0")
        self.separation = float(wheel_separation_m)
        self.max_speed = float(max_speed_mps)
        self.x = float(x)
        self.y = float(y)
        self.yaw = float(yaw)
        self.left = 0.0  # wheel speeds now, m/s
        self.right = 0.0
        self.left_accel = 0.0  # the accelerations of the last step, m/s²
        self.right_accel = 0.0
        self.travel = (0.0, 0.0)  # cumulative (left, right) wheel travel, m
        self._cmd = (0.0, 0.0)
        self._accel = (1.0, 1.0)

    def command(
        self, left: float, right: float, accel: float, right_accel: float | None = None
    ) -> None:
        """New wheel speed targets (m/s), reached at `accel` (m/s², each wheel; a second value
        for the right wheel). Non-finite values stop the wheel; speeds are clamped."""
        top = self.max_speed
        lv = left if math.isfinite(left) else 0.0
        rv = right if math.isfinite(right) else 0.0
        self._cmd = (min(top, max(-top, lv)), min(top, max(-top, rv)))
        ra = accel if right_accel is None else right_accel
        self._accel = (_positive(accel), _positive(ra))

    @property
    def commanded(self) -> tuple[float, float]:
        """The wheel speeds being ramped toward."""
        return self._cmd

    def stop(self, accel: float | None = None) -> None:
        """Brake both wheels to zero (at `accel`, or the last one given)."""
        a = self._accel if accel is None else (_positive(accel), _positive(accel))
        self._cmd = (0.0, 0.0)
        self._accel = a

    @property
    def speed(self) -> float:
        """Forward speed, m/s."""
        return (self.left + self.right) * 0.5

    @property
    def turn_rate(self) -> float:
        """Yaw rate, rad/s (counter-clockwise positive)."""
        return (self.right - self.left) / self.separation

    @property
    def moving(self) -> bool:
        """Whether either wheel turns."""
        return self.left != 0.0 or self.right != 0.0

    def step(self, dt: float) -> None:
        """Advance by `dt` seconds."""
        l0, r0 = self.left, self.right
        left = _toward(l0, self._cmd[0], self._accel[0] * dt)
        right = _toward(r0, self._cmd[1], self._accel[1] * dt)
        self.left, self.right = left, right
        self.left_accel = (left - l0) / dt if dt > 0 else 0.0
        self.right_accel = (right - r0) / dt if dt > 0 else 0.0
        if left == 0.0 and right == 0.0:
            return
        v = (left + right) * 0.5
        w = (right - left) / self.separation
        yaw0 = self.yaw
        dtheta = w * dt
        if abs(dtheta) < 1e-9:
            self.x += v * dt * math.cos(yaw0)
            self.y += v * dt * math.sin(yaw0)
        else:
            radius = v / w
            self.x += radius * (math.sin(yaw0 + dtheta) - math.sin(yaw0))
            self.y -= radius * (math.cos(yaw0 + dtheta) - math.cos(yaw0))
        self.yaw = math.remainder(yaw0 + dtheta, 2.0 * math.pi)
        tl, tr = self.travel
        self.travel = (tl + left * dt, tr + right * dt)


def _positive(a: float) -> float:
    """An acceleration usable as a ramp: finite and > 0 (else a gentle 0.1 m/s²)."""
    return a if math.isfinite(a) and a > 0 else 0.1


def wheel_speeds(v: float, w: float, separation: float, max_speed: float) -> tuple[float, float]:
    """(left, right) wheel speeds for forward speed `v` and turn rate `w`, both scaled down
    together when a wheel would pass `max_speed` (the turn radius is kept, as husky_base does)."""
    half = w * separation * 0.5
    left, right = v - half, v + half
    top = max(abs(left), abs(right))
    if top > max_speed > 0:
        k = max_speed / top
        left, right = left * k, right * k
    return left, right


__all__ = ["DiffDrive", "wheel_speeds"]
