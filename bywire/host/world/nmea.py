"""NMEA 0183 decoding for the pose server (seed 003 Sec. II-h, seed 000 Sec. 2.3): a GPS/INS on a serial line.

Two pure pieces and their combination:

- `LineSplitter`: bytes arrive from a serial port in arbitrary chunks; it buffers them and yields one
  candidate sentence per ``$``. A line end is LF (CR LF and a lone CR before it are stripped). A ``$`` in
  the middle of a line starts a new sentence: the text before it was cut off (bytes lost on the line) and is
  dropped as ``partial``. A line that grows past `MAX_LINE_BYTES` without a line end is dropped as
  ``overlong`` and the buffer resynchronises on the next ``$``, so memory stays bounded whatever arrives.
- `decode_sentence`: one sentence (bytes from ``$`` up to, not including, the line end) to a typed record,
  or `NmeaError` with the `DropReason` and what was wrong. Nothing else is raised (fuzz-tested).
- `NmeaStream`: both, counting every dropped sentence by reason and every accepted one by type; it never
  raises on input.

Checksums are mandatory (NMEA 0183 v2.3+ requires them on every sentence we decode): ``*hh``, the XOR of
every byte between ``$`` and ``*``, two hex digits, either case.

Sentences decoded: GGA (position, fix quality incl. 4 = RTK fixed and 5 = RTK float), RMC (speed and course
over ground, date, mode), VTG (course and speed), GST (position error statistics: per-axis 1-sigma, which
the pose filter prefers over a table by fix quality), and heading: HDT (true heading, from a dual-antenna
receiver such as seed 000's 2-m baseline) and THS (true heading with a mode: A autonomous, E estimated /
dead reckoning, M manual, S simulator, V invalid; NMEA 4.x replacement of HDT). Talkers: the GNSS ones
(GP GL GA GB BD GQ GI GN), IN (integrated navigation: a GPS/INS), HE (north-seeking gyro) and II.
Everything else (GSA, GSV, ZDA, proprietary ``$P...``) is counted and dropped.

Numbers are parsed strictly (digits, one optional decimal point, a sign only where NMEA allows one):
Python's ``float()`` would also accept "nan", "inf", "1e5" and "1_0", none of which a receiver sends.
Empty fields are legal NMEA ("no value") and decode to None; a required field that is empty is an error.
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum

KNOT_MPS = 1852.0 / 3600.0
KMH_MPS = 1.0 / 3.6
# NMEA 0183 limits a sentence to 82 characters including $ and CR LF. Some INS emit longer proprietary
# sentences; 256 keeps those whole (we drop them anyway) while bounding the buffer on a line without LF.
MAX_LINE_BYTES = 256

GNSS_TALKERS = frozenset({"GP", "GL", "GA", "GB", "BD", "GQ", "GI", "GN"})
TALKERS = GNSS_TALKERS | {"IN", "HE", "II"}
SENTENCE_TYPES = frozenset({"GGA", "RMC", "VTG", "GST", "HDT", "THS"})


class DropReason(StrEnum):
    CHECKSUM = "checksum"  # *hh present and wrong
    NO_CHECKSUM = "no_checksum"  # a complete line without *hh at its end
    PARTIAL = "partial"  # cut off: text before a '$', or a sentence a new '$' interrupted
    OVERLONG = "overlong"  # no line end within MAX_LINE_BYTES
    GARBAGE = "garbage"  # bytes outside printable ASCII
    PROPRIETARY = "proprietary"  # $P... manufacturer sentences
    UNKNOWN_TALKER = "unknown_talker"
    UNKNOWN_TYPE = "unknown_type"  # a well-formed sentence we do not decode (GSA, GSV, ...)
    MALFORMED = "malformed"  # a sentence we decode whose fields are wrong


class NmeaError(ValueError):
    """A sentence that cannot be used; `reason` says which kind, the message says what and where."""

    def __init__(self, reason: DropReason, detail: str) -> None:
        super().__init__(f"{reason.value}: {detail}")
        self.reason = reason
        self.detail = detail


class FixQuality:
    """GGA fix quality indicator (field 6)."""

    INVALID = 0
    GPS = 1
    DGPS = 2
    PPS = 3
    RTK_FIXED = 4
    RTK_FLOAT = 5
    ESTIMATED = 6  # dead reckoning inside the receiver / INS
    MANUAL = 7
    SIMULATOR = 8


@dataclass(frozen=True, slots=True)
class Gga:
    talker: str
    utc_s: float | None  # seconds of the UTC day
    lat_deg: float | None
    lon_deg: float | None
    quality: int
    num_sats: int | None
    hdop: float | None
    alt_m: float | None
    diff_age_s: float | None


@dataclass(frozen=True, slots=True)
class Rmc:
    talker: str
    utc_s: float | None
    valid: bool  # status A
    lat_deg: float | None
    lon_deg: float | None
    speed_mps: float | None
    course_deg: float | None  # true course over ground
    date: tuple[int, int, int] | None  # (year, month, day)
    mode: str | None  # NMEA 2.3: A autonomous, D differential, E estimated, F RTK float, R RTK fixed, N none


@dataclass(frozen=True, slots=True)
class Vtg:
    talker: str
    course_deg: float | None
    speed_mps: float | None
    mode: str | None


@dataclass(frozen=True, slots=True)
class Gst:
    talker: str
    utc_s: float | None
    rms_m: float | None
    lat_std_m: float | None
    lon_std_m: float | None
    alt_std_m: float | None


@dataclass(frozen=True, slots=True)
class Heading:
    talker: str
    kind: str  # "HDT" or "THS"
    heading_deg: float | None  # true heading, degrees clockwise from true north
    valid: bool
    mode: str | None  # THS mode indicator; None for HDT


NmeaRecord = Gga | Rmc | Vtg | Gst | Heading

_UNSIGNED = re.compile(r"\d+(\.\d*)?|\.\d+")
_SIGNED = re.compile(r"-?(\d+(\.\d*)?|\.\d+)")
_TIME = re.compile(r"(\d\d)(\d\d)(\d\d(\.\d+)?)")
_DATE = re.compile(r"(\d\d)(\d\d)(\d\d)")
_ADDRESS = re.compile(r"[A-Z][A-Z0-9]{4}")
_HEX = frozenset("0123456789abcdefABCDEF")


def checksum(body: bytes) -> int:
    """XOR of the bytes between '$' and '*'."""
    c = 0
    for b in body:
        c ^= b
    return c


def with_checksum(body: str) -> bytes:
    """A complete sentence line ``$body*hh\\r\\n`` (used by the receiver emulator and the tests)."""
    raw = body.encode("ascii")
    return b"$" + raw + b"*" + f"{checksum(raw):02X}".encode("ascii") + b"\r\n"


class _Fields:
    """Field access with errors that name the sentence, the field's index and its meaning."""

    def __init__(self, kind: str, fields: list[str]) -> None:
        self.kind = kind
        self.fields = fields

    def _err(self, i: int, name: str, why: str) -> NmeaError:
        return NmeaError(DropReason.MALFORMED, f"{self.kind} field {i + 1} ({name}): {why}")

    def text(self, i: int) -> str:
        return self.fields[i] if i < len(self.fields) else ""

    def number(
        self, i: int, name: str, signed: bool = False, lo: float | None = None, hi: float | None = None
    ) -> float | None:
        s = self.text(i)
        if s == "":
            return None
        if not (_SIGNED if signed else _UNSIGNED).fullmatch(s):
            raise self._err(i, name, f"not a number: {s[:16]!r}")
        v = float(s)
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise self._err(i, name, f"{v} outside [{lo}, {hi}]")
        return v

    def integer(self, i: int, name: str) -> int | None:
        s = self.text(i)
        if s == "":
            return None
        if not s.isascii() or not s.isdigit() or len(s) > 6:
            raise self._err(i, name, f"not an integer: {s[:16]!r}")
        return int(s)

    def utc(self, i: int) -> float | None:
        s = self.text(i)
        if s == "":
            return None
        m = _TIME.fullmatch(s)
        if m is None:
            raise self._err(i, "UTC time", f"not hhmmss.ss: {s[:16]!r}")
        h, mi, sec = int(m.group(1)), int(m.group(2)), float(m.group(3))
        if h > 23 or mi > 59 or sec >= 61.0:
            raise self._err(i, "UTC time", f"out of range: {s!r}")
        return h * 3600.0 + mi * 60.0 + sec

    def coordinate(self, i: int, name: str, hemispheres: str, max_deg: float) -> float | None:
        """ddmm.mmmm / dddmm.mmmm at field i, hemisphere letter at i + 1."""
        s, h = self.text(i), self.text(i + 1)
        if s == "" and h == "":
            return None
        if s == "" or h == "":
            raise self._err(i, name, "value or hemisphere missing")
        if not _UNSIGNED.fullmatch(s):
            raise self._err(i, name, f"not a number: {s[:16]!r}")
        v = float(s)
        deg = int(v // 100.0)
        minutes = v - 100.0 * deg
        if minutes >= 60.0:
            raise self._err(i, name, f"minutes {minutes:.4f} >= 60")
        value = deg + minutes / 60.0
        if value > max_deg:
            raise self._err(i, name, f"{value:.6f} deg beyond {max_deg}")
        if h not in hemispheres:
            raise self._err(i + 1, name + " hemisphere", f"{h[:4]!r} is not one of {hemispheres}")
        return -value if h == hemispheres[1] else value

    def letter(self, i: int, name: str, allowed: str) -> str | None:
        s = self.text(i)
        if s == "":
            return None
        if len(s) != 1 or s not in allowed:
            raise self._err(i, name, f"{s[:8]!r} is not one of {allowed}")
        return s

    def require(self, n: int) -> None:
        if len(self.fields) < n:
            raise NmeaError(DropReason.MALFORMED, f"{self.kind} has {len(self.fields)} fields, needs {n}")


def _gga(talker: str, f: _Fields) -> Gga:
    f.require(6)
    quality = f.integer(5, "fix quality")
    if quality is None or quality > 8:
        raise f._err(5, "fix quality", f"{f.text(5)[:8]!r} is not 0..8")
    lat = f.coordinate(1, "latitude", "NS", 90.0)
    lon = f.coordinate(3, "longitude", "EW", 180.0)
    if quality != FixQuality.INVALID and (lat is None or lon is None):
        raise f._err(1, "position", f"empty with fix quality {quality}")
    alt = f.number(8, "altitude", signed=True, lo=-1e4, hi=1e5)
    return Gga(
        talker=talker,
        utc_s=f.utc(0),
        lat_deg=lat,
        lon_deg=lon,
        quality=quality,
        num_sats=f.integer(6, "satellites"),
        hdop=f.number(7, "HDOP", hi=100.0),
        alt_m=alt,
        diff_age_s=f.number(12, "age of differential", hi=1e5),
    )


def _rmc(talker: str, f: _Fields) -> Rmc:
    f.require(9)
    status = f.letter(1, "status", "AV")
    if status is None:
        raise f._err(1, "status", "empty")
    speed_kn = f.number(6, "speed over ground", hi=1000.0)
    date_text = f.text(8)
    date: tuple[int, int, int] | None = None
    if date_text:
        m = _DATE.fullmatch(date_text)
        if m is None or not (1 <= int(m.group(1)) <= 31 and 1 <= int(m.group(2)) <= 12):
            raise f._err(8, "date", f"not ddmmyy: {date_text[:16]!r}")
        yy = int(m.group(3))
        # Two-digit year: GPS began in 1980, so 80-99 are the 1900s.
        date = (1900 + yy if yy >= 80 else 2000 + yy, int(m.group(2)), int(m.group(1)))
    lat = f.coordinate(2, "latitude", "NS", 90.0)
    lon = f.coordinate(4, "longitude", "EW", 180.0)
    if status == "A" and (lat is None or lon is None):
        raise f._err(2, "position", "empty with status A")
    return Rmc(
        talker=talker,
        utc_s=f.utc(0),
        valid=status == "A",
        lat_deg=lat,
        lon_deg=lon,
        speed_mps=None if speed_kn is None else speed_kn * KNOT_MPS,
        course_deg=f.number(7, "course over ground", hi=360.0),
        date=date,
        mode=f.letter(11, "mode", "ADEFRNPMSO"),
    )


def _vtg(talker: str, f: _Fields) -> Vtg:
    f.require(8)
    course = f.number(0, "course true", hi=360.0)
    speed_kn = f.number(4, "speed knots", hi=1000.0)
    speed_kmh = f.number(6, "speed km/h", hi=2000.0)
    if speed_kmh is not None:
        speed = speed_kmh * KMH_MPS
    elif speed_kn is not None:
        speed = speed_kn * KNOT_MPS
    else:
        speed = None
    return Vtg(talker=talker, course_deg=course, speed_mps=speed, mode=f.letter(8, "mode", "ADEFRNPMSO"))


def _gst(talker: str, f: _Fields) -> Gst:
    f.require(8)
    return Gst(
        talker=talker,
        utc_s=f.utc(0),
        rms_m=f.number(1, "range rms", hi=1e5),
        lat_std_m=f.number(5, "latitude std", hi=1e5),
        lon_std_m=f.number(6, "longitude std", hi=1e5),
        alt_std_m=f.number(7, "altitude std", hi=1e5),
    )


def _hdt(talker: str, f: _Fields) -> Heading:
    f.require(1)
    heading = f.number(0, "heading", hi=360.0)
    return Heading(talker=talker, kind="HDT", heading_deg=heading, valid=heading is not None, mode=None)


def _ths(talker: str, f: _Fields) -> Heading:
    f.require(2)
    heading = f.number(0, "heading", hi=360.0)
    mode = f.letter(1, "mode", "AEMSV")
    # Only an autonomous (measured) heading is a heading measurement; E is the INS's own dead reckoning.
    return Heading(
        talker=talker, kind="THS", heading_deg=heading, valid=heading is not None and mode == "A", mode=mode
    )


_DECODERS: dict[str, Callable[[str, _Fields], NmeaRecord]] = {
    "GGA": _gga,
    "RMC": _rmc,
    "VTG": _vtg,
    "GST": _gst,
    "HDT": _hdt,
    "THS": _ths,
}


def _split_checksum(sentence: bytes, cut_off: bool) -> bytes:
    """The body between '$' and '*', checksum verified."""
    star = sentence.rfind(b"*")
    tail = sentence[star + 1 :] if star >= 0 else b""
    if star < 0 or len(tail) != 2 or not all(chr(b) in _HEX for b in tail):
        if cut_off:
            raise NmeaError(DropReason.PARTIAL, f"cut off by a new '$': {sentence[:24]!r}")
        raise NmeaError(DropReason.NO_CHECKSUM, f"no *hh at the end: {sentence[-24:]!r}")
    body = sentence[1:star]
    want = int(tail, 16)
    got = checksum(body)
    if got != want:
        raise NmeaError(DropReason.CHECKSUM, f"*{tail.decode()} but the sentence XORs to {got:02X}")
    return body


def decode_sentence(sentence: bytes, cut_off: bool = False) -> NmeaRecord:
    """Decode one sentence (from '$' up to the checksum, no line end).

    `cut_off` tells that another '$' followed on the same line (a sentence without checksum is then
    partial rather than missing its checksum). Raises only `NmeaError`.
    """
    if not sentence.startswith(b"$"):
        raise NmeaError(DropReason.PARTIAL, f"does not start with '$': {sentence[:24]!r}")
    if any(b < 0x20 or b > 0x7E for b in sentence):
        raise NmeaError(DropReason.GARBAGE, f"bytes outside printable ASCII in {sentence[:24]!r}")
    body = _split_checksum(sentence, cut_off).decode("ascii")
    address, _, rest = body.partition(",")
    if address.startswith("P"):
        raise NmeaError(DropReason.PROPRIETARY, f"proprietary sentence {address[:12]!r}")
    if not _ADDRESS.fullmatch(address):
        raise NmeaError(DropReason.MALFORMED, f"address field {address[:12]!r} is not talker + type")
    talker, kind = address[:2], address[2:]
    if talker not in TALKERS:
        raise NmeaError(DropReason.UNKNOWN_TALKER, f"talker {talker!r} in {address!r}")
    decoder = _DECODERS.get(kind)
    if decoder is None:
        raise NmeaError(DropReason.UNKNOWN_TYPE, f"sentence type {kind!r} in {address!r}")
    return decoder(talker, _Fields(address, rest.split(",") if body.find(",") >= 0 else []))


class LineSplitter:
    """Incremental byte stream -> candidate sentences (each starting with '$'), with drop counts."""

    def __init__(self, max_line_bytes: int = MAX_LINE_BYTES) -> None:
        self.max_line_bytes = max_line_bytes
        self._buf = bytearray()
        self.drops: Counter[str] = Counter()

    def feed(self, data: bytes) -> list[tuple[bytes, bool]]:
        """Sentences completed by `data`, each with its cut-off flag (another '$' followed on its line)."""
        self._buf += data
        out: list[tuple[bytes, bool]] = []
        while True:
            nl = self._buf.find(b"\n")
            if nl < 0:
                break
            line = bytes(self._buf[:nl])
            del self._buf[: nl + 1]
            self._split_line(line.rstrip(b"\r"), out)
        if len(self._buf) > self.max_line_bytes:
            # No line end for too long: drop all but a '$'-started tail short enough to be a sentence.
            dollar = self._buf.rfind(b"$", len(self._buf) - self.max_line_bytes + 1)
            self.drops[DropReason.OVERLONG.value] += 1
            del self._buf[: dollar if dollar >= 0 else len(self._buf)]
        return out

    def _split_line(self, line: bytes, out: list[tuple[bytes, bool]]) -> None:
        parts = line.split(b"$")
        head = parts[0]
        if head.strip(b" \t\r"):
            printable = all(0x20 <= b <= 0x7E or b == 0x09 for b in head)
            self.drops[(DropReason.PARTIAL if printable else DropReason.GARBAGE).value] += 1
        for k in range(1, len(parts)):
            out.append((b"$" + parts[k].rstrip(b"\r"), k < len(parts) - 1))

    @property
    def pending_bytes(self) -> int:
        return len(self._buf)


class NmeaStream:
    """Bytes in, records out; every dropped sentence counted in `drops` by reason, every kept one in
    `accepted` by sentence type. Never raises on input."""

    def __init__(self, max_line_bytes: int = MAX_LINE_BYTES) -> None:
        self.splitter = LineSplitter(max_line_bytes)
        self.accepted: Counter[str] = Counter()
        self._drops: Counter[str] = Counter()
        self.last_error: str = ""

    def feed(self, data: bytes) -> list[NmeaRecord]:
        records: list[NmeaRecord] = []
        for sentence, cut_off in self.splitter.feed(data):
            try:
                rec = decode_sentence(sentence, cut_off)
            except NmeaError as e:
                self._drops[e.reason.value] += 1
                self.last_error = str(e)
                continue
            self.accepted[type(rec).__name__.upper() if not isinstance(rec, Heading) else rec.kind] += 1
            records.append(rec)
        return records

    @property
    def drops(self) -> Counter[str]:
        """Dropped sentences and line fragments by `DropReason` value."""
        return self._drops + self.splitter.drops
