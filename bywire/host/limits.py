"""The acceleration band the host's controllers command within: the GCDC 2011 rules' limits (seed 003
section V-A: -4.5 .. 2.0 m/s^2), which are also the ECU's default clamp (DESIGN section 4). One place, so
that the override controller, the platoon's QPs and its lead compensation cannot drift apart; the ECU's
calibration stays the authority on what is applied."""

from __future__ import annotations

ACCEL_MIN_MPS2 = -4.5
ACCEL_MAX_MPS2 = 2.0
