"""Pure codecs and unit conversions: round trips (property-based) and known frames."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers import codec

i32 = st.integers(-(2**31), 2**31 - 1)


@given(sw=st.integers(0, 0xFFFF), pos=i32, mode=st.integers(-128, 127))
def test_tpdo1_round_trip(sw, pos, mode):
    status = codec.DriveStatus(sw, pos, mode)
    data = codec.pack_tpdo1(status)
    assert len(data) == 7
    assert codec.unpack_tpdo1(data) == status


def test_tpdo1_byte_layout_is_little_endian_as_mapped_in_the_eds():
    data = codec.pack_tpdo1(codec.DriveStatus(0x1637, -2, 1))
    assert data == bytes([0x37, 0x16, 0xFE, 0xFF, 0xFF, 0xFF, 0x01])


@given(pos=i32)
def test_target_round_trip(pos):
    assert codec.unpack_target(codec.pack_target(pos)) == pos


@given(cw=st.integers(0, 0xFFFF))
def test_controlword_round_trip(cw):
    assert codec.unpack_controlword(codec.pack_controlword(cw)) == cw


@given(mode=st.integers(-128, 127))
def test_mode_round_trip(mode):
    assert codec.unpack_mode(codec.pack_mode(mode)) == mode


@pytest.mark.parametrize("bad", [b"", b"\x00" * 6, b"\x00" * 8])
def test_malformed_tpdo_is_refused(bad):
    with pytest.raises(ValueError, match="TPDO1 must be 7 bytes"):
        codec.unpack_tpdo1(bad)


def test_position_outside_int32_is_refused():
    with pytest.raises(ValueError, match="INTEGER32"):
        codec.pack_target(2**31)


@pytest.mark.parametrize("state", codec.STATES)
def test_every_state_word_decodes_to_its_state(state):
    word = codec.statusword_for(state, target_reached=True, ack=True, following_error=True, internal_limit=True)
    assert codec.state_name(word) == state


@pytest.mark.parametrize(
    ("word", "state"),
    [
        (0x0250, "SWITCH_ON_DISABLED"),
        (0x0231, "READY_TO_SWITCH_ON"),
        (0x0233, "SWITCHED_ON"),
        (0x1637, "OPERATION_ENABLED"),
        (0x0217, "QUICK_STOP_ACTIVE"),
        (0x0218, "FAULT"),
        (0x0000, "NOT_READY_TO_SWITCH_ON"),
    ],
)
def test_known_statuswords(word, state):
    # words as real drives send them (bit 4 voltage enabled, bit 9 remote, bits 10/12 in operation)
    assert codec.state_name(word) == state


def test_statusword_agrees_with_canopen_base_node_402():
    from canopen.profiles.p402 import State402

    for state in codec.STATES:
        word = codec.statusword_for(state)
        mask, value = State402.SW_MASK[state.replace("_", " ")]
        assert word & mask == value


@pytest.mark.parametrize(
    ("cw", "command"),
    [
        (0x06, "SHUTDOWN"),
        (0x07, "SWITCH_ON"),
        (0x0F, "ENABLE_OPERATION"),
        (0x1F, "ENABLE_OPERATION"),
        (0x00, "DISABLE_VOLTAGE"),
        (0x02, "QUICK_STOP"),
        (0x80, "FAULT_RESET"),
        (0x8F, "FAULT_RESET"),
    ],
)
def test_controlword_commands(cw, command):
    assert codec.command_of(cw) == command


@given(code=st.integers(0, 0xFFFF), reg=st.integers(0, 0xFF), extra=st.binary(max_size=5))
def test_emcy_round_trip(code, reg, extra):
    e = codec.Emcy(code, reg, extra.ljust(5, b"\x00"))
    assert codec.unpack_emcy(codec.pack_emcy(e)) == e


def test_emcy_texts():
    assert codec.emcy_text(0x8611) == "following error"
    assert "heartbeat" in codec.emcy_text(0x8130)
    assert codec.emcy_text(0x2311).startswith("current") or "0x2311" in codec.emcy_text(0x2311)
    assert codec.emcy_text(0x1234) == "generic error (0x1234)"


def test_emcy_agrees_with_canopen_decoder():
    from canopen.emcy import EmcyConsumer

    got = []
    consumer = EmcyConsumer()
    consumer.add_callback(got.append)
    consumer.on_emcy(0x82, codec.pack_emcy(codec.Emcy(0x8611, 0x81)), 0.0)
    assert got[0].code == 0x8611 and got[0].register == 0x81


@given(producer=st.integers(1, 127), ms=st.integers(0, 0xFFFF))
def test_consumer_heartbeat_entry_round_trip(producer, ms):
    assert codec.split_consumer_heartbeat_entry(codec.consumer_heartbeat_entry(producer, ms)) == (
        producer,
        ms,
    )


@given(state=st.sampled_from([0x00, 0x04, 0x05, 0x7F]))
def test_heartbeat_round_trip(state):
    assert codec.unpack_heartbeat(codec.pack_heartbeat(state)) == state


@given(counts=i32, cpu=st.sampled_from([1.0, 100.0, 1000.0, 4096 / 360.0, 131072 / 360.0]))
def test_counts_to_unit_and_back_is_exact(counts, cpu):
    assert codec.to_counts(codec.from_counts(counts, cpu), cpu) == counts


@given(value=st.floats(-2000, 2000, allow_nan=False), cpu=st.sampled_from([100.0, 1000.0, 131072 / 360.0]))
def test_unit_to_counts_error_is_at_most_half_a_count(value, cpu):
    counts = codec.to_counts(value, cpu)
    assert abs(codec.from_counts(counts, cpu) - value) <= 0.5 / cpu + 1e-12


def test_non_finite_value_has_no_counts():
    with pytest.raises(ValueError):
        codec.to_counts(float("nan"), 1000.0)


def test_frame_bits():
    # an 8-byte standard frame: 108 bits + 3 IFS without stuffing, at most 24 stuff bits
    assert codec.frame_bits(8, stuffing=False) == 111
    assert codec.frame_bits(8) == 111 + 24
    assert codec.frame_bits(0, stuffing=False) == 47
    assert codec.frame_bits(8, extended=True, stuffing=False) == 131
    with pytest.raises(ValueError):
        codec.frame_bits(9)
