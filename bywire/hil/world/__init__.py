"""The simulated world of the cooperative scenarios (seed 003): roads as lanes, traffic vehicles with
driver models, the radar, GPS receiver and V2V radio that see it, and the bookkeeping that judges it (gaps,
TTC, collisions).

Pure models here (`road`, `drivers`, `traffic`, `sensors`, `v2v`); the byte and datagram links to the host
are in `links`. The plant steps the world at its events (~100 Hz), never every millisecond.
"""
