"""The plant's trace: the columns the simulator writes every millisecond (`bywire.host.trace` writes
and reads the files)."""

from __future__ import annotations

PLANT_COLUMNS = (
    "t_s",
    "speed_mps",
    "accel_mps2",
    "distance_m",
    "x_m",
    "y_m",
    "heading_rad",
    "yaw_rate_radps",
    "throttle_cmd_pct",
    "brake_cmd_bar",
    "steer_cmd_rad",
    "throttle_applied_pct",
    "brake_applied_bar",
    "brake_actual_bar",
    "steer_actual_rad",
    "engage",
    "ecu_state",
    "estop_mode",
    "driver_brake_pct",
    "grade_pct",
    "lead_gap_m",
    "lead_speed_mps",
    "cmd_fresh",
)
