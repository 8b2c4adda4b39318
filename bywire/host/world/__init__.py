"""The host's world model for cooperative driving (seed 003 Sec. II and IV): pose, vehicles, map, radar."""
