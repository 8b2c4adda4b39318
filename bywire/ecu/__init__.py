"""The ECU firmware (DESIGN section 4; seed 000 sections 2-3): the safety authority and its state machine,
the cascaded acceleration controller with pedal feedforward and anti-windup, the watchdogs, the 1 kHz
cyclic executive, the calibration, and the store that flashes, boots and rolls back signed images. It
imports only `bywire.protocol` and the standard library, so its image is a self-contained zipapp."""
