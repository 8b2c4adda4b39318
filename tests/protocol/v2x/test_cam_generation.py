"""The CAM generation rules of EN 302 637-2 6.1.3 (`protocol.v2x.cam_generation`): the rhythm a moving,
turning, braking or standing car gets, T_GenCam's memory of the last rhythm, and the 100 ms / 1 s bounds
for any history of checks."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.protocol.v2x.cam_generation import (
    N_GEN_CAM,
    T_GEN_CAM_MAX_S,
    T_GEN_CAM_MIN_S,
    CamGenerationRules,
)

EPOCH = 1_305_374_400.0  # UNIX seconds: the checks run on generation times this large


State = tuple[float, float, float, float]  # x, y, heading, speed


def _cams(rules: CamGenerationRules, states: list[State], step_s: float) -> list[float]:
    """Times (s after EPOCH) of the CAMs generated for (x, y, heading, speed) checked every step_s."""
    out = []
    for k, (x, y, h, v) in enumerate(states):
        t = k * step_s
        if rules.due(EPOCH + t, x, y, h, v):
            out.append(round(t, 6))
    return out


def test_standing_still_a_cam_a_second() -> None:
    states = [(0.0, 0.0, 0.0, 0.0)] * 31
    assert _cams(CamGenerationRules(), states, 0.1) == [0.0, 1.0, 2.0, 3.0]


def test_at_100_kmh_checked_every_100_ms_every_other_check() -> None:
    v = 27.78  # 2.78 m a check: 4 m is passed at the second one
    states = [(v * 0.1 * k, 0.0, 0.0, v) for k in range(21)]
    rules = CamGenerationRules()
    assert _cams(rules, states, 0.1) == pytest.approx([0.2 * k for k in range(11)])
    assert rules.t_gen_cam_s == pytest.approx(0.2)


def test_checked_every_40_ms_the_first_check_past_4_m() -> None:
    v = 27.78  # 4 m after 144 ms: the check at 160 ms
    states = [(v * 0.04 * k, 0.0, 0.0, v) for k in range(26)]
    expected = [0.0, 0.16, 0.32, 0.48, 0.64, 0.8, 0.96]
    assert _cams(CamGenerationRules(), states, 0.04) == pytest.approx(expected)


def test_a_turn_or_a_speed_change_triggers_after_100_ms() -> None:
    turned = [(0.0, 0.0, math.radians(4.5) * min(k, 1), 0.0) for k in range(5)]
    # turned at 50 ms, sent at 100 ms (T_GenCamDcc); its 100 ms rhythm is then kept by time (T_GenCam)
    assert _cams(CamGenerationRules(), turned, 0.05) == [0.0, 0.1, 0.2]
    # 4 deg exactly is not "more than 4 deg"; across +-pi the change is the short way round
    four = [(0.0, 0.0, 0.0, 0.0), (0.0, 0.0, math.radians(4.0), 0.0)]
    assert _cams(CamGenerationRules(), four, 0.1) == [0.0]
    wrap = [(0.0, 0.0, math.pi - 0.01, 0.0), (0.0, 0.0, -math.pi + 0.01, 0.0)]
    assert _cams(CamGenerationRules(), wrap, 0.1) == [0.0]
    braking = [(0.0, 0.0, 0.0, 20.0 - 6.0 * 0.1 * k) for k in range(3)]  # -0.6 m/s a check
    assert _cams(CamGenerationRules(), braking, 0.1) == [0.0, 0.1, 0.2]


def test_t_gen_cam_keeps_the_last_rhythm_for_three_cams_then_one_second() -> None:
    rules = CamGenerationRules()
    assert rules.due(EPOCH, 0.0, 0.0, 0.0, 20.0)
    assert not rules.due(EPOCH + 0.1, 0.0, 0.0, 0.0, 20.0)
    assert rules.due(EPOCH + 0.3, 5.0, 0.0, 0.0, 20.0)  # moved: the rhythm is now 300 ms
    assert rules.t_gen_cam_s == pytest.approx(0.3)
    # It stops moving (the same place, the same speed: nothing triggers): three CAMs at 300 ms...
    quiet = [(5.0, 0.0, 0.0, 20.0)] * 40
    times = [round(0.3 + 0.1 * k, 6) for k, s in enumerate(quiet) if rules.due(EPOCH + 0.3 + 0.1 * k, *s)]
    assert times[:N_GEN_CAM] == pytest.approx([0.6, 0.9, 1.2])
    # ... then T_GenCamMax again
    assert times[N_GEN_CAM] == pytest.approx(1.2 + T_GEN_CAM_MAX_S)
    assert rules.t_gen_cam_s == T_GEN_CAM_MAX_S


def test_a_clock_set_back_starts_afresh_and_dcc_is_bounded() -> None:
    rules = CamGenerationRules()
    assert rules.due(EPOCH + 5.0, 0.0, 0.0, 0.0, 0.0)
    assert rules.due(EPOCH + 1.0, 0.0, 0.0, 0.0, 0.0)
    assert not rules.due(EPOCH + 1.5, 0.0, 0.0, 0.0, 0.0)
    slow = CamGenerationRules(t_gen_cam_dcc_s=0.5)  # congestion control widening the minimum
    assert _cams(slow, [(10.0 * k, 0.0, 0.0, 20.0) for k in range(11)], 0.1) == [0.0, 0.5, 1.0]
    for bad in (0.05, 1.5):
        with pytest.raises(ValueError, match="t_gen_cam_dcc_s"):
            CamGenerationRules(t_gen_cam_dcc_s=bad)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.integers(min_value=10, max_value=100),  # ms since the last check (T_CheckCamGen <= 100 ms)
            st.floats(-50.0, 50.0),
            st.floats(-50.0, 50.0),
            st.floats(-math.pi, math.pi),
            st.floats(0.0, 60.0),
        ),
        min_size=2,
        max_size=120,
    )
)
def test_cams_are_never_closer_than_100_ms_nor_further_than_a_second_and_a_check(
    checks: list[tuple[int, float, float, float, float]],
) -> None:
    rules = CamGenerationRules()
    t_ms, sent = 0, []
    for dt_ms, x, y, h, v in checks:
        t_ms += dt_ms
        if rules.due(EPOCH + t_ms / 1000.0, x, y, h, v):
            sent.append(t_ms)
    assert sent and sent[0] == checks[0][0]  # the first check sends
    gaps = [b - a for a, b in itertools.pairwise(sent)]
    assert all(g >= T_GEN_CAM_MIN_S * 1000 for g in gaps)
    assert all(g < T_GEN_CAM_MAX_S * 1000 + 100 for g in gaps)
    assert t_ms - sent[-1] < T_GEN_CAM_MAX_S * 1000 + 100
