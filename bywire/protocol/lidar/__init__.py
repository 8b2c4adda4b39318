"""LIDAR messages between the plant (or a sensor driver) and the host (seed 000 sections 2.3 and 4).

A package of its own, beside `v2x`, because it needs numpy: the ECU's firmware image carries the
protocol's top level and only what the ECU's end of the CANopen link needs, and the ECU never sees
a scan.
"""
