"""NMEA 0183 decoding of the pose server (cooperative driving): known sentences, checksums, the byte-stream
splitter, drop reasons, pynmea2 as an independent oracle, and fuzzing (random and mutated input never raises
or hangs)."""

from __future__ import annotations

import pynmea2
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.host.world.nmea import (
    KNOT_MPS,
    MAX_LINE_BYTES,
    DropReason,
    FixQuality,
    Gga,
    Gst,
    Heading,
    LineSplitter,
    NmeaError,
    NmeaStream,
    Rmc,
    Vtg,
    checksum,
    decode_sentence,
    with_checksum,
)

# The classic examples of the NMEA references (their published checksums).
GGA = b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47"
RMC = b"$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A"
RTK_GGA = with_checksum("GNGGA,092725.00,5128.2480000,N,00537.3800000,E,4,14,0.80,20.000,M,47.000,M,1.0,0001")


def test_known_gga() -> None:
    rec = decode_sentence(GGA)
    assert isinstance(rec, Gga)
    assert rec.talker == "GP"
    assert rec.utc_s == 12 * 3600 + 35 * 60 + 19
    assert rec.lat_deg == pytest.approx(48 + 7.038 / 60, abs=1e-12)
    assert rec.lon_deg == pytest.approx(11 + 31.0 / 60, abs=1e-12)
    assert (rec.quality, rec.num_sats, rec.hdop, rec.alt_m, rec.diff_age_s) == (1, 8, 0.9, 545.4, None)


def test_rtk_fixed_gga_and_hemispheres() -> None:
    rec = decode_sentence(RTK_GGA.rstrip())
    assert isinstance(rec, Gga) and rec.quality == FixQuality.RTK_FIXED and rec.diff_age_s == 1.0
    south_west = decode_sentence(
        with_checksum("GPGGA,000000.00,3352.1000,S,15112.6000,W,5,10,1.0,10.0,M,,M,,").rstrip()
    )
    assert isinstance(south_west, Gga)
    assert south_west.lat_deg == pytest.approx(-(33 + 52.1 / 60))
    assert south_west.lon_deg == pytest.approx(-(151 + 12.6 / 60))
    assert south_west.quality == FixQuality.RTK_FLOAT


def test_known_rmc_vtg_hdt_ths_gst() -> None:
    rmc = decode_sentence(RMC)
    assert isinstance(rmc, Rmc) and rmc.valid
    assert rmc.speed_mps == pytest.approx(22.4 * KNOT_MPS)
    assert rmc.course_deg == 84.4 and rmc.date == (1994, 3, 23)
    vtg = decode_sentence(with_checksum("GPVTG,054.7,T,034.4,M,005.5,N,010.2,K,A").rstrip())
    assert isinstance(vtg, Vtg) and vtg.course_deg == 54.7
    assert vtg.speed_mps == pytest.approx(10.2 / 3.6)  # km/h preferred over knots (finer)
    hdt = decode_sentence(with_checksum("HEHDT,274.07,T").rstrip())
    assert hdt == Heading("HE", "HDT", 274.07, True, None)
    ths_dr = decode_sentence(with_checksum("INTHS,12.5,E").rstrip())
    assert isinstance(ths_dr, Heading) and not ths_dr.valid  # estimated: not a measurement
    gst = decode_sentence(with_checksum("GNGST,092725.00,0.02,0.01,0.01,0.0,0.012,0.015,0.03").rstrip())
    assert isinstance(gst, Gst) and (gst.lat_std_m, gst.lon_std_m) == (0.012, 0.015)


def test_no_fix_gga_has_empty_fields() -> None:
    rec = decode_sentence(with_checksum("GNGGA,120000.00,,,,,0,00,99.99,,M,,M,,").rstrip())
    assert isinstance(rec, Gga) and rec.quality == 0 and rec.lat_deg is None and rec.lon_deg is None


@pytest.mark.parametrize(
    ("sentence", "reason"),
    [
        (GGA[:-2] + b"48", DropReason.CHECKSUM),
        (GGA[:-3], DropReason.NO_CHECKSUM),
        (b"$GPGGA,123519,4807.038,N*", DropReason.NO_CHECKSUM),
        (b"GPGGA,123519*47", DropReason.PARTIAL),
        (b"$GPGGA,12\xff519*47", DropReason.GARBAGE),
        (with_checksum("PUBX,00,1").rstrip(), DropReason.PROPRIETARY),
        (with_checksum("XXGGA,1").rstrip(), DropReason.UNKNOWN_TALKER),
        (with_checksum("GPGSV,3,1,11").rstrip(), DropReason.UNKNOWN_TYPE),
        (with_checksum("GPGGA,123519,4807.038,N,01131.000,E,9,08").rstrip(), DropReason.MALFORMED),
        (with_checksum("GPGGA,123519,4867.038,N,01131.000,E,1,08").rstrip(), DropReason.MALFORMED),
        (with_checksum("GPGGA,123519,nan,N,01131.000,E,1,08").rstrip(), DropReason.MALFORMED),
        (with_checksum("GPGGA,123519,4807.038,N,01131.000,E,1e1,08").rstrip(), DropReason.MALFORMED),
        (with_checksum("GPGGA,256060,4807.038,N,01131.000,E,1,08").rstrip(), DropReason.MALFORMED),
        (with_checksum("GPGGA,123519,,,,,1,08").rstrip(), DropReason.MALFORMED),
        (with_checksum("GPRMC,123519,X,4807.038,N,01131.000,E,1,2,230394").rstrip(), DropReason.MALFORMED),
        (with_checksum("GPRMC,123519,A,4807.038,N").rstrip(), DropReason.MALFORMED),
        (with_checksum("gpgga,1").rstrip(), DropReason.MALFORMED),
    ],
)
def test_errors_name_their_reason(sentence: bytes, reason: DropReason) -> None:
    with pytest.raises(NmeaError) as e:
        decode_sentence(sentence)
    assert e.value.reason is reason
    assert e.value.detail


def test_malformed_names_the_field() -> None:
    with pytest.raises(NmeaError, match=r"GPGGA field 2 \(latitude\): minutes"):
        decode_sentence(with_checksum("GPGGA,123519,4867.038,N,01131.000,E,1,08").rstrip())


def test_lowercase_checksum_accepted() -> None:
    assert isinstance(decode_sentence(GGA[:-2] + GGA[-2:].lower()), Gga)


def test_checksum_matches_pynmea2() -> None:
    for body in ("GPGGA,1,2,3", "HEHDT,274.07,T", "GNRMC,,V,,,,,,,,,,N"):
        line = with_checksum(body).decode().strip()
        assert pynmea2.NMEASentence.checksum(body) == checksum(body.encode())
        pynmea2.parse(line, check=True)  # raises on a wrong checksum


def test_splitter_handles_crlf_lone_lf_and_cut_sentences() -> None:
    sp = LineSplitter()
    out = sp.feed(GGA + b"\r\n" + RMC + b"\n" + b"$GPGGA,12,3" + RMC + b"\r\n" + b"junk text\r\n\r\n")
    assert [s for s, _ in out] == [GGA, RMC, b"$GPGGA,12,3", RMC]
    assert [cut for _, cut in out] == [False, False, True, False]
    assert sp.drops == {"partial": 1}


def test_stream_counts_partial_sentence_cut_by_next_dollar() -> None:
    s = NmeaStream()
    recs = s.feed(b"$GPGGA,12,3" + RMC + b"\r\n")
    assert len(recs) == 1 and isinstance(recs[0], Rmc)
    assert s.drops == {"partial": 1}


def test_overlong_line_is_bounded_and_resynchronises() -> None:
    s = NmeaStream()
    s.feed(b"x" * (3 * MAX_LINE_BYTES))
    assert s.splitter.pending_bytes <= MAX_LINE_BYTES
    assert s.drops["overlong"] >= 1
    recs = s.feed(b"\r\n" + GGA + b"\r\n")
    assert len(recs) == 1 and isinstance(recs[0], Gga)


@given(st.lists(st.integers(1, 40), min_size=1, max_size=60))
def test_any_chunking_gives_the_same_records(cuts: list[int]) -> None:
    data = (GGA + b"\r\n" + RMC + b"\r\n" + RTK_GGA) * 3 + b"$GPZZZ,1*00\r\n"
    whole = NmeaStream()
    expected = whole.feed(data)
    chunked = NmeaStream()
    got = []
    pos = 0
    for n in cuts * (len(data) // max(sum(cuts), 1) + 1):
        got += chunked.feed(data[pos : pos + n])
        pos += n
        if pos >= len(data):
            break
    got += chunked.feed(data[pos:])
    assert got == expected and len(got) == 9
    assert chunked.drops == whole.drops


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=600))
def test_fuzz_random_bytes_never_raise(data: bytes) -> None:
    s = NmeaStream()
    s.feed(data)
    s.feed(b"\r\n")
    assert s.splitter.pending_bytes <= MAX_LINE_BYTES
    assert all(reason in {r.value for r in DropReason} for reason in s.drops)


@st.composite
def _mutated_sentence(draw: st.DrawFn) -> bytes:
    base = bytearray(
        draw(st.sampled_from([GGA, RMC, RTK_GGA.rstrip(), with_checksum("HEHDT,274.07,T").rstrip()]))
    )
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.integers(0, 2))
        i = draw(st.integers(0, len(base) - 1))
        if op == 0:
            base[i] = draw(st.integers(0, 255))
        elif op == 1:
            del base[i]
        else:
            base.insert(i, draw(st.sampled_from(b",.*$-0123456789ANSEW\r\n")))
    fix = draw(st.booleans())
    if fix and b"*" in base[1:]:
        # Recompute the checksum so the mutation reaches the field parser.
        body = bytes(base[1 : base.rindex(b"*")])
        base = bytearray(b"$" + body + b"*" + f"{checksum(body):02X}".encode())
    return bytes(base)


def _decode_or_nmea_error(sentence: bytes) -> None:
    try:
        rec = decode_sentence(sentence)
    except NmeaError:
        return
    assert isinstance(rec, Gga | Rmc | Vtg | Gst | Heading)


@settings(max_examples=250, deadline=None)
@given(_mutated_sentence())
def test_fuzz_mutated_sentences_decode_or_raise_nmea_error(sentence: bytes) -> None:
    _decode_or_nmea_error(sentence)


@pytest.mark.slow
@settings(max_examples=20000, deadline=None)
@given(_mutated_sentence())
def test_fuzz_mutated_sentences_long_campaign(sentence: bytes) -> None:
    _decode_or_nmea_error(sentence)


@settings(max_examples=100, deadline=None)
@given(st.lists(_mutated_sentence(), min_size=1, max_size=8))
def test_fuzz_stream_of_mutations_counts_everything(sentences: list[bytes]) -> None:
    s = NmeaStream()
    recs = s.feed(b"\r\n".join(sentences) + b"\r\n")
    assert len(recs) == sum(s.accepted.values())
