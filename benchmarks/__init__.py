"""bywire's benchmarks, kept apart from its pass/fail tests: `bywire bench NAME` runs the module NAME
here (ecu, roadnet, runtime, platoon, v2x, world, urban: rows of `bywire.cli.COMMANDS`), and
`python benchmarks/run.py` the ECU core step, the vehicle-CAN codec and the SIL speed.

DESIGN.md section 5: timing on these machines is noisy, so every benchmark prints distributions
(median / p99 / max) and ratios to a baseline measured in the same run, and nothing here is
asserted. The folder belongs to the source checkout, not to the installed package: `bywire bench`
looks for it beside the `bywire` package it runs from.
"""
