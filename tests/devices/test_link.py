"""SerialLink.exchange: the one retry loop under every protocol (loop:// echoes requests)."""

from __future__ import annotations

import pytest

from devices.errors import DeviceResetError, DeviceTimeoutError, FrameTimeoutError, RequestDamagedError
from devices.link import LineFramer, SerialLink


def _never_reconnects() -> Exception:
    raise AssertionError("loop:// does not disconnect")


def test_the_answer_ends_the_exchange_and_noise_before_it_is_skipped() -> None:
    sent = iter(["noise", "PING"])
    with SerialLink("loop://", LineFramer(), "echo", timeout_s=0.2) as link:
        heard = []

        def answer(line: str) -> str | None:
            heard.append(line)
            return line if line == "PING" else None

        value = link.exchange(lambda: next(sent), answer, retries=3, on_reconnect=_never_reconnects)
        assert value == "PING"
        assert heard == ["noise", "PING"]  # the first try's echo was not the answer: it timed out, then resent
        assert link.faults_recovered == 1


def test_a_request_the_device_keeps_calling_damaged_fails_after_the_retries_naming_it() -> None:
    tries = []

    def damaged(line: str) -> None:
        tries.append(line)
        raise RequestDamagedError(f"{line} arrived damaged")

    with SerialLink("loop://", LineFramer(), "echo", timeout_s=0.2) as link:
        with pytest.raises(DeviceTimeoutError, match=r"did not answer 'G0 X1' after 3 tries.*arrived damaged"):
            link.exchange(lambda: "G0 X1", damaged, retries=2, on_reconnect=_never_reconnects)
        assert tries == ["G0 X1"] * 3 and link.faults_recovered == 3


def test_a_device_that_stays_silent_times_out_every_try() -> None:
    with SerialLink("loop://", LineFramer(), "echo", timeout_s=0.02) as link:
        with pytest.raises(DeviceTimeoutError, match="after 2 tries"):
            link.exchange(lambda: "?", lambda line: None, retries=1, on_reconnect=_never_reconnects)
        assert link.faults_recovered == 2


def test_a_vanished_device_is_reopened_and_the_protocol_told_to_redo_its_step() -> None:
    link = SerialLink("loop://", LineFramer(), "echo", timeout_s=0.2)
    link.open()
    link._port.close()  # the device went away under us
    told = []

    def reconnected() -> Exception:
        told.append(link.reconnects)
        return DeviceResetError("echo reconnected")

    with pytest.raises(DeviceResetError, match="echo reconnected"):
        link.exchange(lambda: "ID?", lambda line: line, retries=3, on_reconnect=reconnected)
    assert told == [1] and link.faults_recovered == 1
    assert link.exchange(lambda: "ID?", lambda line: line, retries=3, on_reconnect=reconnected) == "ID?"
    link.close()


def test_links_work_over_any_pyserial_url():
    with SerialLink("loop://", LineFramer(), "echo", timeout_s=0.2) as link:
        link.send("#1 ID?*00000000")
        assert link.receive() == "#1 ID?*00000000"
        with pytest.raises(FrameTimeoutError):
            link.receive(0.05)
