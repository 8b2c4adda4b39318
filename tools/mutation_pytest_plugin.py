"""pytest plugin for mutation runs only; tools/mutation.py copies it next to the tests it stages.

A mutant's verdict must depend on the mutant alone. Hypothesis would otherwise draw new examples
on every run and replay, from its example database, failures that an earlier mutant caused, so
the same mutant could be killed in one run and survive the next. And a mutant must be killed by an
assertion, never by timing: mutmut's trampolines slow every call of a mutated file, which would
trip Hypothesis' deadline and too-slow health check on the clean code as much as on the mutant.
Tests' own @settings still override what they name (max_examples, ...).
"""

from __future__ import annotations

from hypothesis import HealthCheck, settings

settings.register_profile(
    "bywire-mutation",
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("bywire-mutation")
