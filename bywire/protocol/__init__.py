"""The contract between the ECU, the host and the car (DESIGN section 3): the vehicle CAN database and its
end-to-end protected codec, the ECU's CANopen object dictionary with the ECU's node and the host's
master, the host link's messages, bus construction from URLs (CAN over UDP included) and, in `v2x`, the
V2V messages of seed 003. It imports no code of the firmware, the host or the simulator."""
