"""V2V/V2I messages (seed 003 section III) in the field's standards: codec, transport and receiver.

- `wire`: encode/decode of every message we send or take, dispatched on the ItsPduHeader:
  - `etsi_cam`: ETSI CAM (EN 302 637-2 v1.4.1, protocolVersion 2; v1.3.2 read) <-> `VehicleState`.
  - `iclcm`: the GCDC 2016 iCLCM <-> `CooperativeState` (what a platoon needs beyond the CAM).
  - `dsrc`: SPATEM / MAPEM (ETSI TS 103 301, ISO TS 19091) <-> `SignalPhases` / `RoadMap`.
- `cam_generation`: when a CAM is due by EN 302 637-2 6.1.3's rules (10 Hz at most, 1 Hz at least).
- `codec`: the SI dataclasses, the ItsPduHeader peek, errors, and the CDD units at the edge.
- `schemas`: the shipped ASN.1 modules (`asn1/`, licences in asn1/LICENSES.md), compiled once per process.
- `roadside`: SPATEM phases placed at their MAPEM stop lines (`TrafficLightState`).
- `transport`: UDP broadcast (`v2x://HOST:PORT`), non-blocking poll with kernel receive stamps, a
  periodic sender.
- `receiver`: `V2vReceiver`, datagrams in, plausible messages out, every rejection counted.
- `fuzz`: hostile datagrams (the paper's CALM fuzzer), against a receiver or flooded over UDP.
- `meter`, `v2x_cli`: loss/corruption and round-trip meters, `bywire v2x meter|echo|ping|fuzz|encode|decode`.

Submodules are imported on use, so that `bywire v2x --help` does not load asn1tools.
"""
