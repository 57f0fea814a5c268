"""record:// writes a session in spy://'s hexdump, replay:// plays it back byte for byte and refuses a host that
sends anything else."""

import io

import pytest
from serial.urlhandler.protocol_spy import FormatHexdump

from devices.errors import DeviceError
from devices.link import LineFramer, SerialLink
from devices.pelco_d import PanTiltHead
from devices.recording import finish_replay, parse_recording
from devices.sim import HeadSimulator


def test_a_spy_hexdump_parses_back_to_the_bytes_it_shows():
    out = io.StringIO()
    spy = FormatHexdump(out, False)  # pyserial's own writer, as spy:// uses it
    sent, answer = b"#7 ID?*0123ABCD\n", bytes(range(256)) + b"ok\r\n"
    spy.tx(sent)
    spy.rx(answer[:100])
    spy.rx(answer[100:])
    spy.control("Q-RX", "reset_input_buffer")
    (connection,) = parse_recording(out.getvalue())
    assert connection.events == [("TX", sent), ("RX", answer)]


def test_a_recorded_head_session_replays_byte_for_byte(tmp_path):
    path = tmp_path / "head.spy"
    with HeadSimulator(speed_deg_s=1000.0) as sim, \
            PanTiltHead(f"record://{sim.url}?file={path}", timeout_s=0.2) as head:
        recorded = [head.move_to(pan, tilt) for pan, tilt in [(5.0, 2.0), (-20.0, 10.0)]]
    text = path.read_text()
    assert " OPEN " in text and " TX " in text and " RX " in text
    with PanTiltHead(f"replay://{path}", timeout_s=0.2) as head:  # no simulator: the recording answers
        replayed = [head.move_to(pan, tilt) for pan, tilt in [(5.0, 2.0), (-20.0, 10.0)]]
    assert replayed == recorded
    session = finish_replay(path)
    assert session.left() == 0 and session.opened == len(session.connections) == 1


def test_a_host_that_sends_something_else_is_stopped_at_the_first_other_byte(tmp_path):
    path = tmp_path / "lines.spy"
    out = io.StringIO()
    spy = FormatHexdump(out, False)
    spy.tx(b"G21 G90\n")
    spy.rx(b"ok\n")
    path.write_text(out.getvalue())
    with SerialLink(f"replay://{path}", LineFramer(), "drives", timeout_s=0.05) as link, \
            pytest.raises(DeviceError, match=r"G21 G91.*recording has b'G21 G90"):
        link.send("G21 G91")
    finish_replay(path)
