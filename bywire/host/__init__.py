"""The host agent (DESIGN sections 1-2; seeds 000 and 003): modules on a real-time runtime (`runtime`) that
turn a car's sensors and a mission into requests to the ECU: the ECU link, odometry and perception, the
urban behaviour on an RNDF/MDF (`roadnet`, `behaviour`), lateral and longitudinal control, cooperative
driving (`world`, `platoon`). It runs on a car with nothing of the simulator (`bywire host run`)."""
