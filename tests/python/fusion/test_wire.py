"""Messages as bytes: every frame decodes to what was encoded, and no damaged frame decodes."""

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from octofuse.fusion.wire import (
    HEADER_BYTES,
    Encoding,
    Kind,
    LayerBlob,
    Message,
    WireError,
    decode,
    decode_layers,
    encode_layers,
)

names = st.text(min_size=0, max_size=20)
messages = st.builds(
    Message,
    fleet=names,
    rule=names,
    sender=names,
    receiver=names,
    seq=st.integers(0, 2**64 - 1),
    ack=st.integers(0, 2**64 - 1),
    kind=st.sampled_from([Kind.WHOLE, Kind.DELTA]),
    payload=st.binary(max_size=300),
)


@given(messages)
def test_a_frame_decodes_to_its_message(msg):
    assert decode(msg.encode()) == msg


@settings(max_examples=60)
@given(messages, st.data())
def test_any_changed_byte_is_refused(msg, data):
    frame = bytearray(msg.encode())
    i = data.draw(st.integers(0, len(frame) - 1))
    frame[i] ^= data.draw(st.integers(1, 255))
    with pytest.raises(WireError):
        decode(bytes(frame))


@settings(max_examples=60)
@given(messages, st.data())
def test_a_truncated_or_extended_frame_is_refused(msg, data):
    frame = msg.encode()
    cut = data.draw(st.integers(0, len(frame) - 1))
    with pytest.raises(WireError):
        decode(frame[:cut])
    with pytest.raises(WireError):
        decode(frame + b"\0")


def test_a_payload_over_the_bound_is_refused_before_reading_it():
    frame = Message("f", "r", "a", "b", 1, 0, Kind.WHOLE, b"x" * 1000).encode()
    with pytest.raises(WireError, match="over the bound of 999 bytes"):
        decode(frame, max_payload=999)
    assert decode(frame, max_payload=1000).payload == b"x" * 1000


def test_foreign_bytes_and_other_versions_are_named():
    with pytest.raises(WireError, match="shorter than the"):
        decode(b"OFM")
    with pytest.raises(WireError, match="not an octofuse message"):
        decode(b"GET / HTTP/1.1\r\n" + bytes(HEADER_BYTES))
    frame = bytearray(Message("f", "r", "a", "b", 1, 0, Kind.WHOLE).encode())
    frame[3] = 2
    with pytest.raises(WireError, match="version 2"):
        decode(bytes(frame))


def test_an_acknowledgement_has_no_payload():
    ack = Message("f", "r", "a", "b", 0, 7, Kind.ACK, encoding=0)
    assert decode(ack.encode()).ack == 7
    with pytest.raises(WireError, match="acknowledgement"):
        decode(Message("f", "r", "a", "b", 0, 7, Kind.ACK, b"x").encode())


def test_names_and_numbers_out_of_range_are_refused_when_encoding():
    with pytest.raises(ValueError, match="sender"):
        Message("f", "r", "a" * 256, "b", 1, 0, Kind.WHOLE).encode()
    with pytest.raises(ValueError, match="seq"):
        Message("f", "r", "a", "b", -1, 0, Kind.WHOLE).encode()


layer_lists = st.lists(
    st.one_of(
        st.builds(
            LayerBlob,
            source=names,
            version=st.integers(0, 2**64 - 1),
            base=st.integers(0, 2**64 - 1),
            data=st.binary(max_size=60),
        ),
        st.builds(LayerBlob, source=names, version=st.integers(0, 2**64 - 1), held=st.just(True)),
    ),
    max_size=5,
)


@given(layer_lists)
def test_a_layers_payload_decodes_to_its_layers(layers):
    payload = encode_layers(layers)
    assert decode_layers(payload) == layers
    msg = Message("f", "source-layers", "a", "b", 1, 0, Kind.WHOLE, payload, Encoding.LAYERS)
    assert decode(msg.encode()) == msg


@settings(max_examples=60)
@given(layer_lists, st.data())
def test_a_truncated_or_extended_layers_payload_is_refused(layers, data):
    payload = encode_layers(layers)
    cut = data.draw(st.integers(0, len(payload) - 1))
    for bad in (payload[:cut], payload + b"\0"):
        with pytest.raises(WireError):
            decode_layers(bad)
        # refused in a frame too, whose checksum is right
        frame = Message("f", "r", "a", "b", 1, 0, Kind.WHOLE, bad, Encoding.LAYERS).encode()
        with pytest.raises(WireError):
            decode(frame)


def test_a_layer_without_a_map_carries_no_data():
    with pytest.raises(ValueError, match="no data"):
        encode_layers([LayerBlob("a", 1, held=True, data=b"x")])
    with pytest.raises(ValueError, match="version"):
        encode_layers([LayerBlob("a", -1)])
    bad = bytearray(encode_layers([LayerBlob("a", 1, data=b"xy")]))
    bad[4 + 2 + 16] = 1  # the flags: a version only, yet two bytes of map
    with pytest.raises(WireError, match="flags 1"):
        decode_layers(bytes(bad))
