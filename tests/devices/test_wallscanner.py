"""The wall scanner's CRC line framing (the driver against its simulator: tests/scanner/test_hardware.py)."""

from devices.wallscanner import CrcLineFramer, Damaged, checksum, frame_line, unframe_line


def test_line_checksums():
    line = frame_line("#3 OK 12")
    assert unframe_line(line) == "#3 OK 12"
    assert unframe_line(line.replace("12", "13")) is None
    assert unframe_line("#3 OK 12") is None
    assert checksum("") == "00000000" and len(checksum("#1 OK")) == 8


def test_the_framer_gives_sound_bodies_and_marks_damaged_lines():
    framer = CrcLineFramer()
    wire = framer.encode("#3 OK 12") + framer.terminator
    assert wire == (frame_line("#3 OK 12") + "\n").encode()
    damaged = wire.replace(b"12", b"13")
    # a line split between reads waits for its newline; a CR before the newline is dropped
    assert framer.feed(wire.replace(b"\n", b"\r\n") + damaged[:5]) == ["#3 OK 12"]
    assert framer.feed(damaged[5:] + wire[:4] + b"\n") == [Damaged(damaged.decode().rstrip("\n")),
                                                           Damaged(wire[:4].decode())]
