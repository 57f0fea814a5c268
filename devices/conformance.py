"""Conformance checks of a wall scanner implementation against its protocol (docs/scanner-protocol.md,
devices/wallscanner.py): what `arproj devices-check scanner URL` runs against a port.

Unlike the host's driver, which retries and skips what it cannot use, the checks send exact lines and judge
every answer line: the id echoed, the checksum sound, the shape and values the protocol prescribes. Each check
gives one `CheckResult`; later checks build on earlier ones (a buffer read back needs a sampling run), so the
sequence runs in order and a check whose precondition failed says so.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

from devices.errors import DeviceError, FrameTimeoutError
from devices.link import SerialLink
from devices.wallscanner import COUNTS_MAX, CrcLineFramer, Damaged, checksum, frame_line

RATE_HZ = 200  # the sampling rate the checks arm with (the host's default, scanner.sensor_model)
PASS_TAG = 7
SAMPLING_S = 0.2  # how long the checks let the device sample (real time; a simulator's clock may stand still)
MAX_ID = 65535
ERR_UNKNOWN, ERR_CHECKSUM, ERR_STATE, ERR_ARGUMENT = 1, 2, 3, 4


class WireFramer(CrcLineFramer):
    """The CRC line framer with encode() sending a line as given: the checks build whole wire lines (a wrong
    checksum among them) with frame_line()."""

    def encode(self, frame: str) -> bytes:
        return frame.encode("ascii", errors="replace")


@dataclass(frozen=True)
class CheckResult:
    name: str
    ok: bool
    detail: str

    def line(self) -> str:
        return f"{'PASS' if self.ok else 'FAIL'} {self.name}: {self.detail}"


class NonConformingError(Exception):
    """A check's finding: the device answered otherwise than the protocol says."""


@dataclass
class _Session:
    link: SerialLink[str | Damaged, str]
    timeout_s: float
    damaged: list[str] = field(default_factory=list)  # answer lines with a bad checksum, over the whole run
    next_id: int = 100
    state: dict[str, int] = field(default_factory=dict)  # what earlier checks learnt (t0, n)

    def new_id(self) -> int:
        self.next_id += 1
        return self.next_id

    def ask(self, body: str, until_end: bool = False, wire: str | None = None) -> list[list[str]]:
        """Send `#<id> body` (or the exact wire line) and return the answer's fields per line (the id
        stripped): one line, or up to END. Raises NonConformingError on a wrong id, a damaged line, silence."""
        tag = body.split()[0]
        self.link.send(frame_line(body) if wire is None else wire)
        lines: list[list[str]] = []
        deadline = time.monotonic() + self.timeout_s
        while True:
            try:
                frame = self.link.receive(deadline=deadline)
            except FrameTimeoutError:
                got = f" after {len(lines)} line(s)" if lines else ""
                raise NonConformingError(f"no answer to {body!r} within {self.timeout_s:g} s{got}") from None
            if isinstance(frame, Damaged):
                self.damaged.append(frame.text)
                raise NonConformingError(f"answer line {frame.text!r} to {body!r} has a wrong checksum")
            fields = frame.split()
            if not fields or fields[0] != tag:
                raise NonConformingError(f"answer {frame!r} to {body!r} does not repeat its id {tag}")
            lines.append(fields[1:])
            if not until_end or fields[1:2] == ["END"] or fields[1:2] == ["ERR"]:
                return lines
            deadline = time.monotonic() + self.timeout_s  # each line of a read-back within the deadline


def _ok_int(s: _Session, command: str) -> int:
    fields = s.ask(f"#{s.new_id()} {command}")[0]
    if len(fields) != 2 or fields[0] != "OK" or not fields[1].isdigit():
        raise NonConformingError(f"{command!r} answered {' '.join(fields)!r}, expected 'OK <integer>'")
    return int(fields[1])


def _expect_error(s: _Session, command: str, code: int, wire: str | None = None, tag: int | None = None) -> str:
    tag = s.new_id() if tag is None else tag
    fields = s.ask(f"#{tag} {command}", wire=wire)[0]
    if len(fields) < 2 or fields[0] != "ERR" or fields[1] != str(code):
        raise NonConformingError(f"{command!r} answered {' '.join(fields)!r}, expected 'ERR {code} <text>'")
    return " ".join(fields)


# ---------------------------------------------------------------------------------------------------- checks
def check_no_buffer_after_connect(s: _Session) -> str:
    return f"GET before any sampling: {_expect_error(s, 'GET 0 1', ERR_STATE)}"


def check_identify(s: _Session) -> str:
    fields = s.ask(f"#{s.new_id()} ID?")[0]
    if len(fields) != 4 or fields[:2] != ["OK", "WALLSCAN"]:
        raise NonConformingError(f"ID? answered {' '.join(fields)!r}, expected 'OK WALLSCAN <model> <firmware>'")
    return " ".join(fields[2:])


def check_request_ids(s: _Session) -> str:
    for tag in (1, 4242, MAX_ID):
        fields = s.ask(f"#{tag} CLK?")[0]
        if fields[:1] != ["OK"]:
            raise NonConformingError(f"#{tag} CLK? answered {' '.join(fields)!r}")
    return f"ids 1, 4242, {MAX_ID} echoed"


def check_clock(s: _Session) -> str:
    a = _ok_int(s, "CLK?")
    b = _ok_int(s, "CLK?")
    if b < a:
        raise NonConformingError(f"the clock ran backwards: {a} then {b} µs")
    return f"{a} then {b} µs"


def check_arm(s: _Session) -> str:
    before = _ok_int(s, "CLK?")
    t0 = _ok_int(s, f"ARM {RATE_HZ} {PASS_TAG}")
    if t0 < before:
        raise NonConformingError(f"ARM gave sample 0 at {t0} µs, before the clock's {before} µs")
    s.state["t0"] = t0
    return f"sample 0 at {t0} µs"


def check_no_read_back_while_armed(s: _Session) -> str:
    if "t0" not in s.state:
        raise NonConformingError("not armed (ARM failed)")
    return f"GET while armed: {_expect_error(s, 'GET 0 1', ERR_STATE)}"


def check_disarm(s: _Session) -> str:
    if "t0" not in s.state:
        raise NonConformingError("not armed (ARM failed)")
    time.sleep(SAMPLING_S)
    n = _ok_int(s, "DISARM")
    if n < 1:
        raise NonConformingError("DISARM buffered no sample: sample 0 is taken when armed")
    s.state["n"] = n
    again = _ok_int(s, "DISARM")
    if again != n:
        raise NonConformingError(f"DISARM again gave {again} samples, the buffer holds {n}")
    return f"{n} samples buffered (DISARM repeated: the same)"


def check_read_back(s: _Session) -> str:
    if "n" not in s.state:
        raise NonConformingError("no buffer (DISARM failed)")
    n, t0 = s.state["n"], s.state["t0"]
    period = round(1e6 / RATE_HZ)
    first = _read(s, 0, n)
    if _read(s, 0, n) != first:
        raise NonConformingError("a second GET of the same samples gave other values (GET must be a pure read)")
    if n > 1:
        tail = _read(s, n - 1, 5)
        if tail != first[-1:]:
            raise NonConformingError(f"GET {n - 1} 5 gave {tail}, expected the last sample alone")
    rest = s.ask(f"#{s.new_id()} GET {n} 3", until_end=True)[0]
    if rest != ["END", "0"]:
        raise NonConformingError(f"GET {n} 3 (past the buffer) answered {' '.join(rest)!r}, expected 'END 0'")
    for k, (t, *_counts) in enumerate(first):
        if t != t0 + k * period:
            raise NonConformingError(f"sample {k} at {t} µs, expected t0 + k·{period} = {t0 + k * period} µs")
    return f"{n} samples, times t0 + k·{period} µs, counts in 0..{COUNTS_MAX}, repeatable"


def _read(s: _Session, first: int, count: int) -> list[tuple[int, ...]]:
    lines = s.ask(f"#{s.new_id()} GET {first} {count}", until_end=True)
    end = lines[-1]
    samples = lines[:-1]
    if end[:1] != ["END"] or len(end) != 2 or end[1] != str(len(samples)):
        raise NonConformingError(f"GET {first} {count} ended with {' '.join(end)!r} after {len(samples)} sample lines, "
                            f"expected 'END {len(samples)}'")
    out = []
    for k, fields in enumerate(samples, start=first):
        if len(fields) != 6 or fields[0] != "S" or not all(f.isdigit() for f in fields[1:]):
            raise NonConformingError(f"sample line {' '.join(fields)!r}, expected 'S <k> <t_us> <ind> <cap> <ac>'")
        values = tuple(int(f) for f in fields[1:])
        if values[0] != k:
            raise NonConformingError(f"sample line numbered {values[0]}, expected {k} (in order, none skipped)")
        if not all(0 <= v <= COUNTS_MAX for v in values[2:]):
            raise NonConformingError(f"sample {k}: counts {values[2:]} outside 0..{COUNTS_MAX}")
        out.append(values[1:])
    return out


def check_bad_checksum(s: _Session) -> str:
    tag = s.new_id()
    body = f"#{tag} CLK?"
    wrong = f"{int(checksum(body), 16) ^ 0x1:08X}"
    return _expect_error(s, "CLK? (checksum altered)", ERR_CHECKSUM, wire=f"{body}*{wrong}", tag=tag)


def check_unknown_command(s: _Session) -> str:
    return _expect_error(s, "SING", ERR_UNKNOWN)


def check_bad_argument(s: _Session) -> str:
    answers = [_expect_error(s, command, ERR_ARGUMENT) for command in ("ARM fast 1", "ARM 0 1", "GET zero 5")]
    return "; ".join(answers)


def check_checksums(s: _Session) -> str:
    if s.damaged:
        raise NonConformingError(f"{len(s.damaged)} answer line(s) with a wrong checksum, e.g. {s.damaged[0]!r}")
    return "every answer line's CRC-32 was right"


CHECKS: tuple[tuple[str, Callable[[_Session], str]], ...] = (
    ("no-buffer-after-connect", check_no_buffer_after_connect),
    ("identify", check_identify),
    ("request-id-echo", check_request_ids),
    ("clock", check_clock),
    ("arm", check_arm),
    ("no-read-back-while-armed", check_no_read_back_while_armed),
    ("disarm", check_disarm),
    ("buffer-read-back", check_read_back),
    ("bad-checksum-refused", check_bad_checksum),
    ("unknown-command", check_unknown_command),
    ("bad-argument", check_bad_argument),
    ("answer-checksums", check_checksums),
)


def run_checks(url: str, timeout_s: float = 0.5) -> list[CheckResult]:
    """Every check against the wall scanner at `url` (a pyserial URL), in order. A port that cannot be opened
    raises DeviceError (an InputError)."""
    link: SerialLink[str | Damaged, str] = SerialLink(url, WireFramer(), "scanner", timeout_s=timeout_s,
                                                      reconnect_attempts=1)
    link.open()
    results = []
    try:
        session = _Session(link, timeout_s)
        for name, check in CHECKS:
            try:
                results.append(CheckResult(name, True, check(session)))
            except NonConformingError as finding:
                results.append(CheckResult(name, False, str(finding)))
                time.sleep(timeout_s)  # what a failed check left on the wire is not the next check's answer
                link.drain()
            except DeviceError as err:
                results.append(CheckResult(name, False, f"the connection failed: {err}"))
                break
    finally:
        link.close()
    return results
