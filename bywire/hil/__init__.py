"""The simulator around the ECU and the host (DESIGN sections 1 and 5): the FMU plant and the world
(roads, traffic, radar, GPS, V2V), scenarios and their faults, the SIL driver and the HIL runner of
separate processes on a virtual bus, evaluation and reports. It builds the host's inputs from a scenario
and starts the same host a car runs."""
