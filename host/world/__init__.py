"""The host's world model for cooperative driving (seed 003 sections II and IV): pose, vehicles, map, radar."""
