"""The CANopen host <-> ECU link: the ECU's node (0x10) and the host's master (0x01), pumped not threaded.

Kammel et al. 2008 (seed 000) Sec. 2.1 and 3: the main computer and the low-level ECU exchange
control requests and status over a dedicated link; Sec. 12: a hung process that its watchdog could
not see stopped the car in the final, so liveness here is explicit both ways (heartbeats with
consumer timeouts) and every request carries an alive counter. DESIGN section 3 (host <-> ECU) and
section 4 (every watchdog time bounded by the firmware).

Both ends sit on the `canopen` package (object dictionary from `ecu.eds`, LocalNode with its SDO
server, RemoteNode with its SDO client), one module per concept, the two ends side by side:

- `dictionary`: the ECU's object dictionary: EDS, indices, the firmware's bounds, SDO abort codes,
  PDO layouts. Shared by both ends.
- `nmt`: NMT states and commands, heartbeat parsing and the heartbeat consumer. Shared.
- `pump`: the threadless network (drain, send) and the event timers both ends step. Shared.
- `ecu_node`: the ECU's end, `EcuNode` (ships in the ECU firmware image).
- `host_master`: the host's end, `HostMaster` (never in the ECU firmware image).
"""
