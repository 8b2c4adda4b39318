"""bywire: drive-by-wire ECU firmware, host agent and HIL plant for automated cars."""

__version__ = "0.1.0"
