"""Pelco-D framing: checksums, angle encoding, resynchronisation after garbage."""

import numpy as np
import pytest

from devices import pelco_d


def test_frame_layout_and_checksum_match_the_protocol():
    # Set pan to 123.45° at address 1: data 12345 = 0x3039; checksum = (1 + 0 + 0x4B + 0x30 + 0x39) & 0xFF
    frame = pelco_d.encode(1, pelco_d.SET_PAN, pelco_d.angle_to_data(123.45))
    assert frame == bytes([0xFF, 0x01, 0x00, 0x4B, 0x30, 0x39, (1 + 0x4B + 0x30 + 0x39) & 0xFF])


@pytest.mark.parametrize("angle", [0.0, 0.01, 45.5, 179.99, -0.01, -30.0, -179.99])
def test_angles_round_trip_at_the_protocol_resolution(angle):
    # half the protocol's 0.01° step (rounded to the nearest)
    assert pelco_d.data_to_angle(pelco_d.angle_to_data(angle)) == pytest.approx(angle, abs=0.005)


def test_decoder_resynchronises_and_rejects_corrupted_frames():
    rng = np.random.default_rng(3)
    good = [pelco_d.encode(1, pelco_d.REPLY_PAN, d) for d in (0, 0xFFFF, 0x00FF, 12345)]
    bad = bytearray(pelco_d.encode(1, pelco_d.REPLY_TILT, 777))
    bad[6] ^= 0x01
    stream = bytes(rng.integers(0, 256, 5, dtype=np.uint8)) + good[0] + bytes(bad) + good[1] + b"\xff\xff" \
        + good[2] + good[3][:3]
    decoder = pelco_d.PelcoDFramer()
    frames = decoder.feed(stream[:9]) + decoder.feed(stream[9:])
    frames += decoder.feed(good[3][3:])
    assert [f.data for f in frames] == [0, 0xFFFF, 0x00FF, 12345]
    assert all(f.command2 == pelco_d.REPLY_PAN for f in frames)
    assert decoder.rejected_bytes >= 7


def test_decoding_does_not_depend_on_how_the_bytes_arrive():
    """Frames, sync bytes and noise fed whole, byte by byte, or in random pieces: the same frames, the same
    rejected bytes (nothing kept past a frame's length)."""
    rng = np.random.default_rng(11)
    parts = [pelco_d.encode(1, pelco_d.REPLY_PAN, int(d)) for d in rng.integers(0, 36000, 40)]
    parts += [b"\xff" * int(k) for k in rng.integers(1, 12, 20)]
    parts += [bytes(rng.integers(0, 256, int(k), dtype=np.uint8)) for k in rng.integers(1, 20, 20)]
    stream = b"".join(parts[i] for i in rng.permutation(len(parts)))
    results = []
    for cuts in ([], list(range(1, len(stream))), sorted(rng.choice(len(stream), 30, replace=False).tolist())):
        decoder = pelco_d.PelcoDFramer()
        pieces = [stream[a:b] for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True)]
        frames = [f for piece in pieces for f in decoder.feed(piece)]
        results.append((frames, decoder.rejected_bytes, len(decoder._buffer)))
    assert results[0] == results[1] == results[2]
    assert len(results[0][0]) >= 40 and results[0][2] < pelco_d.FRAME_LENGTH
