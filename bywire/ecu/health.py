"""The running ECU's health, as its boot status reports it to the boot supervisor (boot.py).

No paper section: DESIGN section 4, "a trial image is confirmed by a period of health, not by being
alive". Healthy means the host link is up (the host's CANopen heartbeat fresh and OPERATIONAL,
`EcuNode.host_alive`) and no internal fault (loop stall, exception inside a cycle, transmit-guard
trip: `EcuApp.internal_fault_events`) has happened since the last time the count was restarted:

- healthy time accumulates between two samples that both saw the link up and no new fault;
- a new internal fault restarts it at 0: an image that faults must then show a whole confirmation
  period without one;
- a link drop only pauses it: the host being switched off is not the image's fault.

Sampled every `SAMPLE_CYCLES` cycles (100 ms at 1 kHz; a link drop shorter than that can go
unnoticed, which shortens nothing by more than one sample), reported at most once per
`REPORT_PERIOD_S` (written by a thread beside the 1 kHz loop: `ecu.boot_reporter`). Pure: time comes
in as arguments.
"""

from __future__ import annotations

from dataclasses import dataclass

FIRST_REPORT_CYCLES = 20  # the executive ran 20 ms: the image is up
SAMPLE_CYCLES = 100  # 10 Hz at 1 kHz, twice per 200 ms host heartbeat consumer time
REPORT_PERIOD_S = 1.0


@dataclass
class BootHealth:
    """Healthy seconds of this boot, from samples of the host link and the internal fault count."""

    healthy_s: float = 0.0
    host_link_up: bool = False
    internal_faults: int = 0
    _last_sample_s: float | None = None
    _next_report_s: float | None = None

    def sample(self, now_s: float, host_link_up: bool, internal_faults: int) -> None:
        if internal_faults != self.internal_faults:
            self.healthy_s = 0.0
        elif (
            host_link_up
            and self.host_link_up
            and self._last_sample_s is not None
            and now_s > self._last_sample_s
        ):
            self.healthy_s += now_s - self._last_sample_s
        self.host_link_up = host_link_up
        self.internal_faults = internal_faults
        self._last_sample_s = now_s

    def report_due(self, now_s: float) -> bool:
        """True at the first call, then at most once per REPORT_PERIOD_S."""
        if self._next_report_s is not None and now_s < self._next_report_s:
            return False
        self._next_report_s = now_s + REPORT_PERIOD_S
        return True
