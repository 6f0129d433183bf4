"""The wire protocol: exact bytes for known messages, and round trips and fuzzing with hypothesis."""

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hardware.protocol import (
    MAX_FRAME_BYTES,
    BoardStatus,
    BoardVersion,
    Frame,
    LineSplitter,
    ProtocolError,
    bar_to_mbar,
    checksum,
    decode,
    encode,
)

# (seq, verb, args) -> the exact bytes on the wire; PROTOCOL.md quotes the first three.
BYTE_TABLE = [
    ((1, "VER", ()), b"$1 VER*E41D\n"),
    ((7, "SET", (1250, 0, 0, 0, 0, 0, 0)), b"$7 SET 1250 0 0 0 0 0 0*7E7F\n"),
    ((None, "NAK", ("CRC",)), b"$? NAK CRC*51C6\n"),
    ((0, "HB", ()), b"$0 HB*C20C\n"),
    ((65535, "VENT", ()), b"$65535 VENT*C7CA\n"),
    ((42, "ACK", ("estop=0", "wdt=1", "mbar=0,2500")), b"$42 ACK estop=0 wdt=1 mbar=0,2500*C72D\n"),
    ((42, "ACK", ("estop=0", "wdt=0", "mbar=0,2500", "bad=3")), b"$42 ACK estop=0 wdt=0 mbar=0,2500 bad=3*F4C3\n"),
]


def test_checksum_is_crc16_ccitt_false():
    assert checksum(b"123456789") == "29B1"  # the published check value of CRC-16/CCITT-FALSE


@pytest.mark.parametrize(("message", "wire"), BYTE_TABLE)
def test_byte_table(message, wire):
    seq, verb, args = message
    assert encode(seq, verb, *args) == wire
    assert decode(wire) == Frame(seq, verb, tuple(str(a) for a in args))
    assert decode(wire.rstrip(b"\n") + b"\r\n") == decode(wire)


@pytest.mark.parametrize(("line", "reason"), [
    (b"hello", "FRAME"),
    (b"", "FRAME"),
    (b"$7 SET 1250*7E7F", "CRC"),
    (b"$7 SET 1250 0 0 0 0 0 0*7e7f", "FRAME"),  # lower-case hex is not accepted
    (b"$7 SET 1250 0 0 0 0 0 0", "FRAME"),
    (b"$" + b"7 SET" + b" 1" * 70 + b"*0000", "FRAME"),
    (b"$07 HB*" + checksum(b"07 HB").encode(), "FRAME"),
    (b"$70000 HB*" + checksum(b"70000 HB").encode(), "FRAME"),
    (b"$1 hb*" + checksum(b"1 hb").encode(), "FRAME"),
    (b"$1  HB*" + checksum(b"1  HB").encode(), "FRAME"),
    (b"$1 HB \xff*" + checksum(b"1 HB \xff").encode(), "FRAME"),
])
def test_malformed_lines_are_named_errors(line, reason):
    with pytest.raises(ProtocolError) as error:
        decode(line)
    assert error.value.reason == reason


@pytest.mark.parametrize(("seq", "verb", "args"), [
    (-1, "HB", ()), (65536, "HB", ()), (True, "HB", ()), (1, "hb", ()), (1, "TOOLONGVERB", ()),
    (1, "SET", ("a b",)), (1, "SET", ("*",)), (1, "SET", ("$",)), (1, "SET", ("",)), (1, "SET", ("9" * 41,)),
    (1, "SET", ("1",) * 70),
])
def test_encode_refuses_what_decode_could_not_read(seq, verb, args):
    with pytest.raises(ValueError):
        encode(seq, verb, *args)


verbs = st.text(alphabet="ABCDEFGHIJKLMNOPQRSTUVWXYZ", min_size=1, max_size=8)
args = st.text(alphabet=[chr(c) for c in range(0x21, 0x7F) if chr(c) not in "$*"], min_size=1, max_size=12)
seqs = st.none() | st.integers(0, 65535)


@given(seqs, verbs, st.lists(args, max_size=6))
def test_round_trip(seq, verb, arguments):
    wire = encode(seq, verb, *arguments)
    assert len(wire) <= MAX_FRAME_BYTES and wire.endswith(b"\n") and wire.count(b"\n") == 1
    assert decode(wire) == Frame(seq, verb, tuple(arguments))


@given(st.binary(max_size=200))
def test_decode_of_arbitrary_bytes_raises_only_protocol_errors(data):
    try:
        frame = decode(data)
    except ProtocolError as e:
        assert e.reason in ("FRAME", "CRC")
    else:
        assert encode(frame.seq, frame.verb, *frame.args).rstrip(b"\n") == data.rstrip(b"\n").rstrip(b"\r")


@given(seqs, verbs, st.lists(args, max_size=6), st.data())
def test_any_single_byte_corruption_is_detected(seq, verb, arguments, data):
    wire = encode(seq, verb, *arguments)
    position = data.draw(st.integers(0, len(wire) - 2))  # every byte before the terminator
    value = data.draw(st.integers(0, 255).filter(lambda b: b != wire[position]))
    corrupted = wire[:position] + bytes([value]) + wire[position + 1:]
    with pytest.raises(ProtocolError):
        decode(corrupted)


@given(st.lists(st.binary(max_size=40), max_size=8), st.lists(st.integers(1, 30), min_size=1, max_size=20))
def test_line_splitter_is_independent_of_read_sizes(lines, cuts):
    stream = b"".join(line.replace(b"\n", b"") + b"\n" for line in lines)
    expected = [line.replace(b"\n", b"").rstrip(b"\r") for line in lines]
    expected = [line for line in expected if line]
    splitter, got, position, i = LineSplitter(), [], 0, 0
    while position < len(stream):
        size = cuts[i % len(cuts)]
        got += splitter.feed(stream[position:position + size])
        position, i = position + size, i + 1
    assert got == expected


def test_line_splitter_reports_an_overlong_line_once_and_recovers():
    splitter = LineSplitter()
    assert splitter.feed(b"x" * 300) == []
    assert splitter.feed(b"yyy\n$1 HB*0000\n") == [LineSplitter.OVERFLOW, b"$1 HB*0000"]


def test_status_and_version_fields_round_trip():
    status = BoardStatus(True, False, (0, 1250, 2500))
    assert BoardStatus.parse(status.fields()) == status
    version = BoardVersion(1, "softarm-emu/0.1.0", 7, 2500, 1465, 250)
    assert BoardVersion.parse(version.fields()) == version
    with pytest.raises(ProtocolError, match="lacks field"):
        BoardStatus.parse(("estop=0",))
    with pytest.raises(ProtocolError, match="bad status"):
        BoardStatus.parse(("estop=2", "wdt=0", "mbar=0"))


@pytest.mark.parametrize(("bar", "limit", "mbar"), [
    (0.0, 2.5, 0), (1.2344, 2.5, 1234), (1.2346, 2.5, 1235), (2.5, 2.5, 2500), (2.4996, 2.4996, 2499),
])
def test_bar_to_mbar_rounds_but_never_exceeds_the_limit(bar, limit, mbar):
    assert bar_to_mbar(bar, limit) == mbar


@pytest.mark.parametrize("bar", [-0.001, 2.5001, float("nan"), float("inf")])
def test_bar_to_mbar_refuses_out_of_range(bar):
    with pytest.raises(ValueError):
        bar_to_mbar(bar, 2.5)


@given(st.floats(0.0, 6.0), st.floats(0.001, 6.0))
def test_bar_to_mbar_never_exceeds_the_limit(bar, limit):
    if bar <= limit:
        assert 0 <= bar_to_mbar(bar, limit) <= limit * 1000


def test_status_carries_the_count_of_unreadable_frames_when_the_board_reports_it():
    wire = b"$42 ACK estop=0 wdt=0 mbar=0,2500 bad=3*F4C3\n"
    status = BoardStatus.parse(decode(wire).args)
    assert status == BoardStatus(False, False, (0, 2500), unreadable_frames=3)
    assert encode(42, "ACK", *status.fields()) == wire
    assert BoardStatus.parse(("estop=0", "wdt=0", "mbar=0")).unreadable_frames is None  # an older firmware
    assert BoardStatus(False, False, (0,)).fields() == ("estop=0", "wdt=0", "mbar=0")


@pytest.mark.parametrize("count", ["-1", "x", "01", "65536", "1.5", ""])
def test_a_count_of_unreadable_frames_that_is_not_a_count_is_a_protocol_error(count):
    with pytest.raises(ProtocolError, match="bad status fields .* is not a count 0..65535"):
        BoardStatus.parse(("estop=0", "wdt=0", "mbar=0", f"bad={count}"))
