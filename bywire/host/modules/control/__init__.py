"""The host's control: seed 000 section 11's longitudinal override and lateral controllers, and seed 003
section V's platoon control; each turns plans and estimates into the `/control/request` the ECU link
sends."""
