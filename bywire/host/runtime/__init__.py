"""The host runtime: a time-stamped object store in the spirit of KogMo-RTDB (seed 000 section 3,
seed 003 section II-c). So far: the in-process store (`store.py`); modules, scheduler, supervisor
and record/replay are still to come (issue 3)."""
