"""V2V/V2I messages (seed 003 section III): an ETSI ITS-G5 CAM-shaped codec, transport and receiver.

- `codec`: our UPER messages (`bywire_v2x.asn`: VehicleState, TrafficLightState, SpeedLimit), SI
  dataclasses, conversions at the edge.
- `etsi_cam`: real ETSI CAMs into the same `VehicleState` (`from_etsi_cam`), `decode_any` for both.
- `transport`: UDP broadcast (`v2x://HOST:PORT`), non-blocking poll with kernel receive stamps, a
  periodic sender.
- `receiver`: `V2vReceiver`, datagrams in, plausible messages out, every rejection counted.
- `fuzz`: hostile datagrams (the paper's CALM fuzzer), against a receiver or flooded over UDP.
- `meter`, `v2x_cli`: loss/corruption and round-trip meters, `bywire v2x meter|echo|ping|fuzz`.
- `bench`: `bywire bench v2x`.

Submodules are imported on use, so that `bywire v2x --help` does not load asn1tools.
"""
