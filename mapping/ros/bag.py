"""A rosbag2 of ROS 2 messages in one MCAP file: the file (CDR messages, the ros2 profile, every schema embedded
as ros2msg text) and `metadata.yaml` beside it, which `ros2 bag info DIR` and rosbag2 readers need to open the
folder as a bag (storage_identifier mcap).

Messages are plain dicts in the shape of their ROS type, CDR-encoded by mcap-ros2-support's encoder (the one its
Writer uses), or bytes already CDR-encoded (`write_cdr`: that encoder packs arrays number by number, 2 µs
each, so the scanner's passes are packed by numpy instead, `CdrBuffer`). `stamp(t_ns)` makes a
builtin_interfaces/Time. Definitions come from msg/ beside this module (`definition`)."""

from __future__ import annotations

import functools
import math
import struct
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import yaml
from mcap.writer import CompressionType, Writer
from mcap_ros2 import __version__ as mcap_ros2_version
from mcap_ros2._dynamic import EncoderFunction, serialize_dynamic
from numpy.typing import NDArray

from geometry.errors import InputError

MSG_DIR = Path(__file__).with_name("msg")
METADATA_NAME = "metadata.yaml"
METADATA_VERSION = 5  # rosbag2's metadata version of Humble, which newer rosbag2 (Jazzy, Kilted) still read
_SEPARATOR = "=" * 80
_HEADER_DEPENDENCY = ("MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n" + _SEPARATOR +
                      "\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n")


@functools.cache
def definition(msgtype: str) -> str:
    """The full ros2msg text of `msgtype` (pkg/msg/Name), dependencies appended as rosbag2 embeds them."""
    pkg, _, name = msgtype.split("/")
    text = (MSG_DIR / f"{pkg}__{name}.msg").read_text()
    if pkg == "arproj_msgs":  # the project's own: a plain .msg whose only dependency is the header
        text = f"{text.rstrip()}\n{_SEPARATOR}\n{_HEADER_DEPENDENCY}"
    return text


def stamp(t_ns: int) -> dict[str, int]:
    return {"sec": int(t_ns // 1_000_000_000), "nanosec": int(t_ns % 1_000_000_000)}


def header(t_ns: int, frame_id: str) -> dict[str, Any]:
    return {"stamp": stamp(t_ns), "frame_id": frame_id}


def quaternion(R: NDArray[np.float64]) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation matrix, w ≥ 0 (Shepperd's method: the largest of the four first, so that no
    division is by a small number; scipy's Rotation costs 30 µs a call, which tf at 4 Hz along a scan notices)."""
    m = np.asarray(R, dtype=np.float64)
    t = m[0, 0] + m[1, 1] + m[2, 2]
    diag = (t, m[0, 0], m[1, 1], m[2, 2])
    k = int(np.argmax(diag))
    if k == 0:
        r = math.sqrt(1.0 + t) * 2.0
        q = (float(m[2, 1] - m[1, 2]) / r, float(m[0, 2] - m[2, 0]) / r, float(m[1, 0] - m[0, 1]) / r, 0.25 * r)
    elif k == 1:
        r = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2.0
        q = (0.25 * r, float(m[0, 1] + m[1, 0]) / r, float(m[0, 2] + m[2, 0]) / r, float(m[2, 1] - m[1, 2]) / r)
    elif k == 2:
        r = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2.0
        q = (float(m[0, 1] + m[1, 0]) / r, 0.25 * r, float(m[1, 2] + m[2, 1]) / r, float(m[0, 2] - m[2, 0]) / r)
    else:
        r = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2.0
        q = (float(m[0, 2] + m[2, 0]) / r, float(m[1, 2] + m[2, 1]) / r, 0.25 * r, float(m[1, 0] - m[0, 1]) / r)
    return (-q[0], -q[1], -q[2], -q[3]) if q[3] < 0 else q


_STRUCT = {code: struct.Struct(f"<{fmt}") for code, fmt in
           (("i1", "b"), ("u1", "B"), ("i4", "i"), ("u4", "I"), ("f4", "f"), ("f8", "d"))}


class CdrBuffer:
    """Little-endian CDR of one message, field by field (alignment counted after the encapsulation header, as
    CDR has it); arrays of numbers go in at once from numpy."""

    def __init__(self) -> None:
        self.out = bytearray(b"\x00\x01\x00\x00")  # CDR_LE, no options

    def _align(self, size: int) -> None:
        self.out += b"\x00" * (-(len(self.out) - 4) % size)

    def number(self, dtype: str, value: float) -> CdrBuffer:
        fmt = _STRUCT[dtype]
        self._align(fmt.size)
        self.out += fmt.pack(value)
        return self

    def doubles(self, *values: float) -> CdrBuffer:
        self._align(8)
        self.out += struct.pack(f"<{len(values)}d", *values)
        return self

    def string(self, text: str) -> CdrBuffer:
        data = text.encode() + b"\x00"
        self.number("u4", len(data))
        self.out += data
        return self

    def header(self, t_ns: int, frame_id: str) -> CdrBuffer:
        return self.number("i4", t_ns // 1_000_000_000).number("u4", t_ns % 1_000_000_000).string(frame_id)

    def array(self, dtype: str, values: Any) -> CdrBuffer:
        d = np.dtype(dtype).newbyteorder("<")
        a = np.ascontiguousarray(values, dtype=d).ravel()
        self.number("u4", len(a))
        if len(a):  # as mcap-ros2-support's encoder: an empty sequence is its length alone
            self._align(d.itemsize)
            self.out += a.tobytes()
        return self

    def bytes(self) -> bytes:
        return bytes(self.out)


def tf_message(transforms: list[tuple[NDArray[np.float64], str, str, int]]) -> bytes:
    """tf2_msgs/TFMessage of (T_parent_from_child, parent, child, t_ns) transforms, CDR-encoded (tf along a
    scan is most of its messages: the dict encoder took 0.3 ms for one)."""
    cdr = CdrBuffer().number("u4", len(transforms))
    for T, parent, child, t_ns in transforms:
        T = np.asarray(T, dtype=np.float64)
        cdr.header(int(t_ns), parent).string(child)
        cdr.doubles(*T[:3, 3].tolist(), *quaternion(T[:3, :3]))

    return cdr.bytes()


def check_path(path: str | Path) -> Path:
    """The bag's .mcap path, refused (InputError) when it cannot be one: another suffix, a folder, no folder to
    put it in, or a metadata.yaml beside it that is not a rosbag2's."""
    path = Path(path)
    if path.suffix != ".mcap":
        raise InputError(f"--record {path}: a recording is an .mcap file", "give a name ending in .mcap")
    if path.is_dir():
        raise InputError(f"--record {path}: is a folder", "give the .mcap file's name")
    if not path.parent.is_dir():
        raise InputError(f"--record {path}: no folder {path.parent}", "create it first")
    meta = path.parent / METADATA_NAME
    if meta.exists() and "rosbag2_bagfile_information" not in meta.read_text(errors="replace"):
        raise InputError(f"{meta}: a file that is not a rosbag2's metadata is in the way",
                         "record into another folder (the bag's metadata.yaml goes beside the .mcap)")
    return path


class RosBag:
    """Write messages into `path` (.mcap); close() finishes the file and writes metadata.yaml beside it. A
    metadata.yaml already there that is not a rosbag2's is refused (InputError), not overwritten."""

    def __init__(self, path: str | Path) -> None:
        self.path = check_path(path)
        self._file = open(self.path, "wb")  # noqa: SIM115 (closed by close())
        self._writer = Writer(self._file, compression=CompressionType.LZ4)  # zstd: 2/3 the size, 1.4 x the time
        self._writer.start(profile="ros2", library=f"arproj, mcap-ros2-support {mcap_ros2_version}")
        self._schemas: dict[str, int] = {}
        self._encoders: dict[str, EncoderFunction] = {}
        self._channels: dict[str, int] = {}
        self.counts: dict[tuple[str, str], int] = {}
        self._t_min: int | None = None
        self._t_max = 0

    def write(self, topic: str, msgtype: str, message: dict[str, Any], t_ns: int) -> None:
        encode = self._encoders.get(msgtype)
        if encode is None:
            encode = self._encoders[msgtype] = serialize_dynamic(msgtype, definition(msgtype))[msgtype]
        self.write_cdr(topic, msgtype, encode(message), t_ns)

    def write_cdr(self, topic: str, msgtype: str, data: bytes, t_ns: int) -> None:
        """A message already CDR-encoded (little-endian, with its 4-byte encapsulation header)."""
        schema = self._schemas.get(msgtype)
        if schema is None:
            schema = self._schemas[msgtype] = self._writer.register_schema(msgtype, "ros2msg",
                                                                          definition(msgtype).encode())
        channel = self._channels.get(topic)
        if channel is None:
            channel = self._channels[topic] = self._writer.register_channel(topic, "cdr", schema)
        key = (topic, msgtype)
        self.counts[key] = self.counts.get(key, 0) + 1
        self._writer.add_message(channel, log_time=int(t_ns), data=data, publish_time=int(t_ns),
                                 sequence=self.counts[key])
        self._t_min = int(t_ns) if self._t_min is None else min(self._t_min, int(t_ns))
        self._t_max = max(self._t_max, int(t_ns))

    def close(self) -> Path:
        """Finish the MCAP file and write metadata.yaml; returns the .mcap path."""
        if self._file.closed:
            return self.path
        self._writer.finish()
        self._file.close()
        start = self._t_min or 0
        duration = max(0, self._t_max - start)
        total = sum(self.counts.values())
        info = {"version": METADATA_VERSION, "storage_identifier": "mcap",
                "relative_file_paths": [self.path.name],
                "duration": {"nanoseconds": duration}, "starting_time": {"nanoseconds_since_epoch": start},
                "message_count": total,
                "topics_with_message_count": [
                    {"topic_metadata": {"name": topic, "type": msgtype, "serialization_format": "cdr",
                                        "offered_qos_profiles": ""}, "message_count": n}
                    for (topic, msgtype), n in self.counts.items()],
                "compression_format": "", "compression_mode": "",
                "files": [{"path": self.path.name, "starting_time": {"nanoseconds_since_epoch": start},
                           "duration": {"nanoseconds": duration}, "message_count": total}]}
        (self.path.parent / METADATA_NAME).write_text(
            yaml.safe_dump({"rosbag2_bagfile_information": info}, sort_keys=False))
        return self.path

    def __enter__(self) -> RosBag:
        return self

    def __exit__(self, kind: type[BaseException] | None, err: BaseException | None, tb: TracebackType | None) -> None:
        self.close()
