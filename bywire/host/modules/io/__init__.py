"""The host's adapters: the modules that talk to the car's hardware and links (the ECU link, vehicle CAN,
the radar, the GPS serial line, V2X, the localisation's object link). They need the host's resources,
so they run in the host process; everything they hand on is data on the store (DESIGN section 1)."""
