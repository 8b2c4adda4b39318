"""The host runtime (seed 000 section 3, seed 003 section II-c): a time-stamped object store in the
spirit of KogMo-RTDB (`store.py`), the modules (`module.py`), the scheduler and the supervisor
(`runtime.py`), thread and process workers, the store across processes (`transport.py`), MCAP recording
and reading, and the live view; the replay of a recording is `host/replay.py`."""
