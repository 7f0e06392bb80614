"""Control messages: trajectory references, vehicle state, per-axle wheel commands."""
from __future__ import annotations

from tether.message import Message


class TrajectoryPoint(Message, tag="control.TrajectoryPoint"):
    """Reference at one instant: pose, its first and second time derivatives (world frame)."""

    t_s: float = 0.0
    x_m: float = 0.0
    y_m: float = 0.0
    theta_rad: float = 0.0
    dx_mps: float = 0.0
    dy_mps: float = 0.0
    dtheta_radps: float = 0.0
    ddx_mps2: float = 0.0
    ddy_mps2: float = 0.0
    ddtheta_radps2: float = 0.0


class VehicleState(Message, tag="control.VehicleState"):
    """Double-Ackermann vehicle state: pose, body speeds and achieved per-axle actuation."""

    x_m: float = 0.0
    y_m: float = 0.0
    theta_rad: float = 0.0
    v_front_mps: float = 0.0
    v_rear_mps: float = 0.0
    delta_front_rad: float = 0.0
    delta_rear_rad: float = 0.0


class WheelCommand(Message, tag="control.WheelCommand"):
    """Per-axle command: wheel (axle-centre) speed and steer angle for the front and rear axles."""

    v_front_mps: float = 0.0
    delta_front_rad: float = 0.0
    v_rear_mps: float = 0.0
    delta_rear_rad: float = 0.0
