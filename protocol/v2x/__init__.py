"""V2V/V2I messages (seed 003 section III): an ETSI ITS-G5 CAM-shaped codec, transport and receiver."""
