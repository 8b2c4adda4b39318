"""A faster UPER encoder and decoder for the messages a GCDC vehicle sends ten times a second, built from
asn1tools' own compiled types; asn1tools stays the reference and takes every value this one does not
fully vouch for.

Why: the heat's nine simulated senders and our own V2V transmitter encode ~200 CAMs and iCLCMs a simulated
second, and asn1tools spends most of an encoding in its type and constraint checking passes and in
per-node method calls. Here every node of the compiled type tree becomes a closure that checks its value
(exact Python type, root range or size, root alternative) and returns its bits, in one pass.

The rule that keeps it bit-identical: a value is encoded here only when it is plainly within the root of
every type it touches; anything else (an extension, an addition present, a DEFAULT member given, an
integer out of range, a type this module does not know, a wrong Python type) raises `Unsupported`, and
the caller encodes with asn1tools as before, so its bytes and its errors are unchanged. What is encoded
here follows asn1tools' UPER encoder (`asn1tools.codecs.uper` and `per`) line by line, and the property
tests (tests/protocol/v2x/test_v2x_fast_uper.py) hold it to asn1tools on random messages of every kind we
send, in range and out of it.

Decoding likewise: a datagram is decoded here only while every bit says root (no extension bit set, every
index a root alternative, every integer and size within its constraint) and the bytes last; anything
else raises `Unsupported` and asn1tools decodes it, giving the value or the error it always gave. The
value decoded here is built as asn1tools builds it (the same Python types, members in the same order, an
absent DEFAULT member as asn1tools' own default object), held to it by property tests on our datagrams,
altered ones and random bytes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from asn1tools.codecs import per, uper

# (value, number of bits) of a node's encoding
Bits = tuple[int, int]
NodeEncoder = Callable[[Any], Bits]


class Unsupported(Exception):
    """This value (or type) is left to asn1tools."""


def _unsupported(_: Any) -> Bits:
    raise Unsupported


def _integer(t: uper.Integer) -> NodeEncoder:
    if t.number_of_bits is None:
        return _unsupported
    lo, hi, nbits = t.minimum, t.maximum, t.number_of_bits
    if t.has_extension_marker:
        nbits += 1  # the extension bit, 0: the value lies in the root range

    def enc(d: Any) -> Bits:
        if type(d) is not int or not lo <= d <= hi:
            raise Unsupported
        return d - lo, nbits

    return enc


def _boolean(_: per.Boolean) -> NodeEncoder:
    def enc(d: Any) -> Bits:
        if type(d) is not bool:
            raise Unsupported
        return int(d), 1

    return enc


def _enumerated(t: per.Enumerated) -> NodeEncoder:
    index = dict(t.root_data_to_index)
    nbits = t.root_number_of_bits + (0 if t.additions_index_to_data is None else 1)

    def enc(d: Any) -> Bits:
        if type(d) is not str or d not in index:
            raise Unsupported
        return index[d], nbits

    return enc


def _bit_string(t: uper.BitString) -> NodeEncoder:
    if t.number_of_bits is None or t.minimum is None:
        return _unsupported
    lo, hi, size_bits = t.minimum, t.maximum, t.number_of_bits
    ext = 1 if t.has_extension_marker else 0
    named = t.has_named_bits
    rstrip = t.rstrip_zeros

    def enc(d: Any) -> Bits:
        if type(d) is not tuple or len(d) != 2:
            raise Unsupported
        data, n = d
        if type(data) is not bytes or type(n) is not int or not lo <= n <= hi or 8 * len(data) < n:
            raise Unsupported
        if named:
            data, n = rstrip(data, n)
            if not lo <= n <= hi or 8 * len(data) < n:
                raise Unsupported
        value, total = 0, ext
        if lo != hi:
            value, total = n - lo, total + size_bits
        if n:
            value = (value << n) | (int.from_bytes(data, "big") >> (8 * len(data) - n))
            total += n
        return value, total

    return enc


def _sequence_of(t: uper.SequenceOf, build: Callable[[Any], NodeEncoder]) -> NodeEncoder:
    if t.number_of_bits is None:
        return _unsupported
    lo, hi, size_bits = t.minimum, t.maximum, t.number_of_bits
    ext = 1 if t.has_extension_marker else 0
    element = build(t.element_type)

    def enc(d: Any) -> Bits:
        if type(d) is not list or not lo <= len(d) <= hi:
            raise Unsupported
        value, total = 0, ext
        if lo != hi:
            value, total = len(d) - lo, total + size_bits
        for item in d:
            v, n = element(item)
            value = (value << n) | v
            total += n
        return value, total

    return enc


def _choice(t: per.Choice, build: Callable[[Any], NodeEncoder]) -> NodeEncoder:
    if t.number_of_indefinite_bits is not None:
        return _unsupported
    ext = 0 if t.additions_index_to_member is None else 1
    index_bits = t.root_number_of_bits if len(t.root_index_to_member) > 1 else 0
    alternatives: dict[str, tuple[int, NodeEncoder]] = {}
    for index, member in t.root_index_to_member.items():
        alternatives[member.name] = (index, build(member))
    head_bits = ext + index_bits

    def enc(d: Any) -> Bits:
        if type(d) is not tuple or len(d) != 2 or type(d[0]) is not str:
            raise Unsupported
        alternative = alternatives.get(d[0])
        if alternative is None:
            raise Unsupported
        index, inner = alternative
        v, n = inner(d[1])
        return (index << n) | v, head_bits + n

    return enc


def _addition_names(t: per.MembersType) -> set[str]:
    names: set[str] = set()
    for addition in t.additions or ():
        if isinstance(addition, per.AdditionGroup):
            names.update(m.name for m in addition.root_members)
            names.update(_addition_names(addition))
        else:
            names.add(addition.name)
    return names


def _sequence(t: per.MembersType, build: Callable[[Any], NodeEncoder]) -> NodeEncoder:
    ext = 0 if t.additions is None else 1
    additions = frozenset(_addition_names(t))
    known = frozenset(m.name for m in t.root_members) | additions
    # Presence bits: an OPTIONAL member's says whether it is given; a DEFAULT member given is left to
    # asn1tools (whether it equals its default is its own question), absent it is a 0.
    optionals = [(m.name, m.optional) for m in t.optionals]
    members = [(m.name, m.optional or m.default is not None, build(m)) for m in t.root_members]

    def enc(d: Any) -> Bits:
        if type(d) is not dict or not known.issuperset(d) or (additions and not additions.isdisjoint(d)):
            raise Unsupported
        value, total = 0, ext
        for name, optional in optionals:
            present = name in d
            if present and not optional:
                raise Unsupported
            value = (value << 1) | present
            total += 1
        for name, may_be_absent, member in members:
            if name in d:
                v, n = member(d[name])
                value = (value << n) | v
                total += n
            elif not may_be_absent:
                raise Unsupported
        return value, total

    return enc


def _made(t: Any, leaves: Any, composites: Any, build: Any, fallback: Any) -> Any:
    """The node function for compiled type `t`: the first kind of `leaves` (maker(t)) or `composites`
    (maker(t, build), building their members with `build`) it is an instance of, else `fallback`
    (octet and character strings, SET, open and recursive types: asn1tools)."""
    for kind, make in leaves:
        if isinstance(t, kind):
            return make(t)
    for kind, make in composites:
        if isinstance(t, kind):
            return make(t, build)
    return fallback


_LEAF_ENCODERS = ((uper.Integer, _integer), (per.Boolean, _boolean), (per.Enumerated, _enumerated),
                  (uper.BitString, _bit_string))  # fmt: skip
_COMPOSITE_ENCODERS = ((uper.SequenceOf, _sequence_of), (per.Choice, _choice), (per.Sequence, _sequence))


def _build(t: Any) -> NodeEncoder:
    encoder: NodeEncoder = _made(t, _LEAF_ENCODERS, _COMPOSITE_ENCODERS, _build, _unsupported)
    return encoder


def compile_encoder(compiled_type: Any, generated: bool = True) -> Callable[[Any], bytes]:
    """An encoder for one asn1tools UPER `CompiledType` (`spec.types[name]`); it raises `Unsupported`
    for any value it leaves to asn1tools. `generated`: as one generated function (see the end of this
    module), else as the tree of closures."""
    if generated:
        return _generated_encoder(compiled_type.type)
    root = _build(compiled_type.type)

    def encode(value: Any) -> bytes:
        v, n = root(value)
        if n == 0:
            return b""
        pad = -n % 8
        return (v << pad).to_bytes((n + pad) // 8, "big")

    return encode


# ---------------------------------------------------------------------------------------------- decoding

# A node decoder takes (the datagram as one integer, its number of bits, the bit position) and returns
# (value, the next position).
NodeDecoder = Callable[[int, int, int], tuple[Any, int]]


def _read(big: int, total: int, pos: int, n: int) -> int:
    end = pos + n
    if end > total:
        raise Unsupported  # out of data: asn1tools says where
    return (big >> (total - end)) & ((1 << n) - 1)


def _read_size(big: int, total: int, pos: int, ext: int, lo: int, hi: int, size_bits: int) -> tuple[int, int]:
    """A constrained size (a bit string's bits, a list's items) at `pos`, within its root: the size and
    the position after it."""
    if ext:
        if _read(big, total, pos, 1):
            raise Unsupported
        pos += 1
    n = lo
    if lo != hi:
        n += _read(big, total, pos, size_bits)
        pos += size_bits
    if n > hi:
        raise Unsupported
    return n, pos


def _undecodable(big: int, total: int, pos: int) -> tuple[Any, int]:
    raise Unsupported


def _integer_decoder(t: uper.Integer) -> NodeDecoder:
    if t.number_of_bits is None:
        return _undecodable
    lo, hi, nbits = t.minimum, t.maximum, t.number_of_bits
    ext = 1 if t.has_extension_marker else 0

    def dec(big: int, total: int, pos: int) -> tuple[Any, int]:
        if ext:
            if _read(big, total, pos, 1):
                raise Unsupported
            pos += 1
        value = _read(big, total, pos, nbits) + lo
        if value > hi:
            raise Unsupported  # asn1tools' constraint check refuses it
        return value, pos + nbits

    return dec


def _boolean_decoder(_: per.Boolean) -> NodeDecoder:
    def dec(big: int, total: int, pos: int) -> tuple[Any, int]:
        return bool(_read(big, total, pos, 1)), pos + 1

    return dec


def _enumerated_decoder(t: per.Enumerated) -> NodeDecoder:
    data = dict(t.root_index_to_data)
    ext = 0 if t.additions_index_to_data is None else 1
    nbits = t.root_number_of_bits

    def dec(big: int, total: int, pos: int) -> tuple[Any, int]:
        if ext:
            if _read(big, total, pos, 1):
                raise Unsupported
            pos += 1
        index = _read(big, total, pos, nbits)
        if index not in data:
            raise Unsupported
        return data[index], pos + nbits

    return dec


def _bit_string_decoder(t: uper.BitString) -> NodeDecoder:
    if t.number_of_bits is None or t.minimum is None:
        return _undecodable
    lo, hi, size_bits = t.minimum, t.maximum, t.number_of_bits
    ext = 1 if t.has_extension_marker else 0

    def dec(big: int, total: int, pos: int) -> tuple[Any, int]:
        n, pos = _read_size(big, total, pos, ext, lo, hi, size_bits)
        bits = _read(big, total, pos, n)
        pad = -n % 8
        return ((bits << pad).to_bytes((n + pad) // 8, "big"), n), pos + n

    return dec


def _sequence_of_decoder(t: uper.SequenceOf, build: Callable[[Any], NodeDecoder]) -> NodeDecoder:
    if t.number_of_bits is None:
        return _undecodable
    lo, hi, size_bits = t.minimum, t.maximum, t.number_of_bits
    ext = 1 if t.has_extension_marker else 0
    element = build(t.element_type)

    def dec(big: int, total: int, pos: int) -> tuple[Any, int]:
        length, pos = _read_size(big, total, pos, ext, lo, hi, size_bits)
        out = []
        for _ in range(length):
            item, pos = element(big, total, pos)
            out.append(item)
        return out, pos

    return dec


def _choice_decoder(t: per.Choice, build: Callable[[Any], NodeDecoder]) -> NodeDecoder:
    ext = 0 if t.additions_index_to_member is None else 1
    index_bits = t.root_number_of_bits if len(t.root_index_to_member) > 1 else 0
    alternatives = {index: (member.name, build(member)) for index, member in t.root_index_to_member.items()}

    def dec(big: int, total: int, pos: int) -> tuple[Any, int]:
        if ext:
            if _read(big, total, pos, 1):
                raise Unsupported
            pos += 1
        index = _read(big, total, pos, index_bits) if index_bits else 0
        alternative = alternatives.get(index)
        if alternative is None:
            raise Unsupported
        name, inner = alternative
        value, pos = inner(big, total, pos + index_bits)
        return (name, value), pos

    return dec


def _sequence_decoder(t: per.MembersType, build: Callable[[Any], NodeDecoder]) -> NodeDecoder:
    ext = 0 if t.additions is None else 1
    n_optional = len(t.optionals)
    optional_bit = {m.name: n_optional - 1 - k for k, m in enumerate(t.optionals)}
    # (name, presence bit or None when always present, decoder, has default, default)
    members = [
        (m.name, optional_bit.get(m.name), build(m), m.has_default(), m.default) for m in t.root_members
    ]

    def dec(big: int, total: int, pos: int) -> tuple[Any, int]:
        if ext:
            if _read(big, total, pos, 1):
                raise Unsupported
            pos += 1
        presence = _read(big, total, pos, n_optional) if n_optional else 0
        pos += n_optional
        values: dict[str, Any] = {}
        for name, bit, member, has_default, default in members:
            if bit is None or presence >> bit & 1:
                values[name], pos = member(big, total, pos)
            elif has_default:
                values[name] = default
        return values, pos

    return dec


_LEAF_DECODERS = ((uper.Integer, _integer_decoder), (per.Boolean, _boolean_decoder),
                  (per.Enumerated, _enumerated_decoder), (uper.BitString, _bit_string_decoder))  # fmt: skip
_COMPOSITE_DECODERS = ((uper.SequenceOf, _sequence_of_decoder), (per.Choice, _choice_decoder),
                       (per.Sequence, _sequence_decoder))  # fmt: skip


def _build_decoder(t: Any) -> NodeDecoder:
    decoder: NodeDecoder = _made(t, _LEAF_DECODERS, _COMPOSITE_DECODERS, _build_decoder, _undecodable)
    return decoder


def compile_decoder(compiled_type: Any, generated: bool = True) -> Callable[[bytes], Any]:
    """A decoder for one asn1tools UPER `CompiledType`; it raises `Unsupported` for any datagram it
    leaves to asn1tools (trailing bytes it ignores, as asn1tools does: the canonical check's business).
    `generated`: as one generated function, else as the tree of closures."""
    if generated:
        return _generated_decoder(compiled_type.type)
    root = _build_decoder(compiled_type.type)

    def decode(data: bytes) -> Any:
        value, _ = root(int.from_bytes(data, "big"), 8 * len(data), 0)
        return value

    return decode


# ---------------------------------------------------------------------------------------- generated code
#
# The closures above cost a call, a tuple and its unpacking per node. For the SEQUENCE, CHOICE, INTEGER,
# ENUMERATED and BOOLEAN nodes (nearly all of a CAM's) the same checks and bits are written out as one
# straight-line function per message type; BIT STRING and SEQUENCE OF nodes call their closures.


class _Source:
    def __init__(self) -> None:
        self.lines: list[str] = []
        self.names: dict[str, Any] = {"Unsupported": Unsupported}
        self._count = 0

    def fresh(self, stem: str) -> str:
        self._count += 1
        return f"{stem}{self._count}"

    def const(self, value: Any, stem: str = "k") -> str:
        name = self.fresh(stem)
        self.names[name] = value
        return name

    def emit(self, depth: int, line: str) -> None:
        self.lines.append("    " * depth + line)

    def compile(self, name: str) -> Any:
        code = "\n".join(self.lines)
        namespace = dict(self.names)
        exec(compile(code, f"<fast_uper {name}>", "exec"), namespace)  # our own generated source
        return namespace[name]


def _emit_bits(src: _Source, depth: int, expr: str, nbits: int) -> None:
    if nbits:
        src.emit(depth, f"v = (v << {nbits}) | ({expr}); n += {nbits}")


def _gen_encode(src: _Source, t: Any, x: str, depth: int) -> None:
    """Code that checks the value in variable `x` and appends its bits to (v, n)."""
    if isinstance(t, uper.Integer) and t.number_of_bits is not None:
        lo, hi = t.minimum, t.maximum
        nbits = t.number_of_bits + (1 if t.has_extension_marker else 0)
        src.emit(depth, f"if type({x}) is not int or not {lo} <= {x} <= {hi}: raise Unsupported")
        _emit_bits(src, depth, f"{x} - {lo}", nbits)
        return
    if isinstance(t, per.Boolean):
        src.emit(depth, f"if type({x}) is not bool: raise Unsupported")
        _emit_bits(src, depth, f"{x}", 1)
        return
    if isinstance(t, per.Enumerated):
        index = src.const(dict(t.root_data_to_index), "idx")
        nbits = t.root_number_of_bits + (0 if t.additions_index_to_data is None else 1)
        i = src.fresh("i")
        src.emit(depth, f"{i} = {index}.get({x}) if type({x}) is str else None")
        src.emit(depth, f"if {i} is None: raise Unsupported")
        _emit_bits(src, depth, i, nbits)
        return
    if isinstance(t, per.Choice) and t.number_of_indefinite_bits is None:
        ext = 0 if t.additions_index_to_member is None else 1
        index_bits = t.root_number_of_bits if len(t.root_index_to_member) > 1 else 0
        a, inner = src.fresh("a"), src.fresh("c")
        src.emit(depth, f"if type({x}) is not tuple or len({x}) != 2 or type({x}[0]) is not str:")
        src.emit(depth + 1, "raise Unsupported")
        src.emit(depth, f"{a}, {inner} = {x}")
        keyword = "if"
        for index, member in t.root_index_to_member.items():
            src.emit(depth, f"{keyword} {a} == {member.name!r}:")
            _emit_bits(src, depth + 1, f"{index}", ext + index_bits)
            _gen_encode(src, member, inner, depth + 1)
            src.emit(depth + 1, "pass")
            keyword = "elif"
        src.emit(depth, "else:")
        src.emit(depth + 1, "raise Unsupported")
        return
    if isinstance(t, per.Sequence):
        additions = frozenset(_addition_names(t))
        known = src.const(frozenset(m.name for m in t.root_members) | additions, "known")
        check = f"type({x}) is not dict or not {known}.issuperset({x})"
        if additions:
            check += f" or not {src.const(additions, 'additions')}.isdisjoint({x})"
        src.emit(depth, f"if {check}: raise Unsupported")
        if t.additions is not None:
            src.emit(depth, "v <<= 1; n += 1")
        for m in t.optionals:
            if not m.optional:  # DEFAULT: given is asn1tools' question, absent a 0
                src.emit(depth, f"if {m.name!r} in {x}: raise Unsupported")
                src.emit(depth, "v <<= 1; n += 1")
            else:
                src.emit(depth, f"v = (v << 1) | ({m.name!r} in {x}); n += 1")
        for m in t.root_members:
            y = src.fresh("m")
            may_be_absent = m.optional or m.default is not None
            src.emit(depth, f"{y} = {x}.get({m.name!r}, Unsupported)")
            src.emit(depth, f"if {y} is not Unsupported:")
            _gen_encode(src, m, y, depth + 1)
            src.emit(depth + 1, "pass")
            if not may_be_absent:
                src.emit(depth, "else:")
                src.emit(depth + 1, "raise Unsupported")
        return
    # BIT STRING, SEQUENCE OF, and what the closures leave to asn1tools: their closure
    f = src.const(_build(t), "node")
    bv, bn = src.fresh("bv"), src.fresh("bn")
    src.emit(depth, f"{bv}, {bn} = {f}({x})")
    src.emit(depth, f"v = (v << {bn}) | {bv}; n += {bn}")


def _generated_encoder(t: Any) -> Callable[[Any], bytes]:
    src = _Source()
    src.emit(0, "def encode(x0):")
    src.emit(1, "v = 0; n = 0")
    _gen_encode(src, t, "x0", 1)
    src.emit(1, "if n == 0: return b''")
    src.emit(1, "pad = -n % 8")
    src.emit(1, "return (v << pad).to_bytes((n + pad) // 8, 'big')")
    encode: Callable[[Any], bytes] = src.compile("encode")
    return encode


def _gen_read(src: _Source, depth: int, target: str, nbits: int) -> None:
    """target = the next nbits bits (an unsigned integer); out of data is Unsupported."""
    src.emit(depth, f"q = p + {nbits}")
    src.emit(depth, "if q > total: raise Unsupported")
    src.emit(depth, f"{target} = (big >> (total - q)) & {(1 << nbits) - 1}; p = q")


def _gen_decode(src: _Source, t: Any, target: str, depth: int) -> None:
    """Code that reads one value into variable `target` (advancing p)."""
    if isinstance(t, uper.Integer) and t.number_of_bits is not None:
        lo, hi, nbits = t.minimum, t.maximum, t.number_of_bits
        if t.has_extension_marker:
            e = src.fresh("e")
            _gen_read(src, depth, e, 1)
            src.emit(depth, f"if {e}: raise Unsupported")
        if nbits:
            _gen_read(src, depth, target, nbits)
            src.emit(depth, f"{target} += {lo}")
        else:
            src.emit(depth, f"{target} = {lo}")
        src.emit(depth, f"if {target} > {hi}: raise Unsupported")
        return
    if isinstance(t, per.Boolean):
        _gen_read(src, depth, target, 1)
        src.emit(depth, f"{target} = bool({target})")
        return
    if isinstance(t, per.Enumerated):
        data = src.const(dict(t.root_index_to_data), "data")
        if t.additions_index_to_data is not None:
            e = src.fresh("e")
            _gen_read(src, depth, e, 1)
            src.emit(depth, f"if {e}: raise Unsupported")
        i = src.fresh("i")
        if t.root_number_of_bits:
            _gen_read(src, depth, i, t.root_number_of_bits)
        else:
            src.emit(depth, f"{i} = 0")
        src.emit(depth, f"{target} = {data}.get({i}, Unsupported)")
        src.emit(depth, f"if {target} is Unsupported: raise Unsupported")
        return
    if isinstance(t, per.Choice):
        if t.additions_index_to_member is not None:
            e = src.fresh("e")
            _gen_read(src, depth, e, 1)
            src.emit(depth, f"if {e}: raise Unsupported")
        index_bits = t.root_number_of_bits if len(t.root_index_to_member) > 1 else 0
        i, inner = src.fresh("i"), src.fresh("c")
        if index_bits:
            _gen_read(src, depth, i, index_bits)
        else:
            src.emit(depth, f"{i} = 0")
        keyword = "if"
        for index, member in t.root_index_to_member.items():
            src.emit(depth, f"{keyword} {i} == {index}:")
            _gen_decode(src, member, inner, depth + 1)
            src.emit(depth + 1, f"{target} = ({member.name!r}, {inner})")
            keyword = "elif"
        src.emit(depth, "else:")
        src.emit(depth + 1, "raise Unsupported")
        return
    if isinstance(t, per.Sequence):
        if t.additions is not None:
            e = src.fresh("e")
            _gen_read(src, depth, e, 1)
            src.emit(depth, f"if {e}: raise Unsupported")
        n_optional = len(t.optionals)
        presence = src.fresh("pr")
        if n_optional:
            _gen_read(src, depth, presence, n_optional)
        optional_bit = {m.name: n_optional - 1 - k for k, m in enumerate(t.optionals)}
        src.emit(depth, f"{target} = {{}}")
        for m in t.root_members:
            y = src.fresh("m")
            bit = optional_bit.get(m.name)
            if bit is None:
                _gen_decode(src, m, y, depth)
                src.emit(depth, f"{target}[{m.name!r}] = {y}")
                continue
            src.emit(depth, f"if {presence} >> {bit} & 1:")
            _gen_decode(src, m, y, depth + 1)
            src.emit(depth + 1, f"{target}[{m.name!r}] = {y}")
            if m.has_default():
                src.emit(depth, "else:")
                src.emit(depth + 1, f"{target}[{m.name!r}] = {src.const(m.default, 'default')}")
        return
    f = src.const(_build_decoder(t), "node")
    src.emit(depth, f"{target}, p = {f}(big, total, p)")


def _generated_decoder(t: Any) -> Callable[[bytes], Any]:
    src = _Source()
    src.emit(0, "def decode(data):")
    src.emit(1, "big = int.from_bytes(data, 'big'); total = 8 * len(data); p = 0")
    _gen_decode(src, t, "x0", 1)
    src.emit(1, "return x0")
    decode: Callable[[bytes], Any] = src.compile("decode")
    return decode
