"""ROS 2 messages in MCAP files, without ROS: the definitions, stamps and the lazy import.

MCAP (rosbag2's default storage since ROS 2 Iron, and Foxglove's native
format) stores each message as CDR bytes on a channel whose schema is the
message's ``ros2msg`` definition text: the message's own fields, then every
type it uses after a line of 80 ``=`` and ``MSG: package/Name``, as rosbag2
writes them. The ``mcap`` and ``mcap-ros2-support`` packages (the ``mcap``
extra: ``pip install 'trajgen[mcap]'``) encode and decode them; they are
imported only by :func:`mcap_writer` and :func:`read_messages`, so
``import trajgen`` stays numpy-only.

Stamps: a time ``t`` (s) on a clock becomes ``builtin_interfaces/Time``
``{sec, nanosec}`` and an MCAP log time of ``round(t * 1e9)`` ns.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from .errors import BadArgument

#: The separator rosbag2 writes between the definitions of one schema.
_SEPARATOR = "=" * 80

_TIME = "int32 sec\nuint32 nanosec\n"
_HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"


def definition(text: str, *uses: tuple[str, str]) -> str:
    """A message definition followed by the definitions of the types it uses."""
    return text + "".join(f"{_SEPARATOR}\nMSG: {name}\n{body}" for name, body in uses)


#: The types a message with a ``std_msgs/Header`` uses (for :func:`definition`).
HEADER_TYPES = (("std_msgs/Header", _HEADER), ("builtin_interfaces/Time", _TIME))

#: ``sensor_msgs/msg/JointState``: rad, rad/s, N m (positions, velocities, efforts).
JOINT_STATE = (
    "sensor_msgs/msg/JointState",
    definition(
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n"
        "float64[] effort\n",
        *HEADER_TYPES,
    ),
)

#: ``trajectory_msgs/msg/JointTrajectory``: what ros2_control's joint trajectory
#: controller takes (quintic segments where points have accelerations).
JOINT_TRAJECTORY = (
    "trajectory_msgs/msg/JointTrajectory",
    definition(
        "std_msgs/Header header\nstring[] joint_names\nJointTrajectoryPoint[] points\n",
        (
            "trajectory_msgs/JointTrajectoryPoint",
            "float64[] positions\nfloat64[] velocities\nfloat64[] accelerations\n"
            "float64[] effort\nbuiltin_interfaces/Duration time_from_start\n",
        ),
        *HEADER_TYPES,
        ("builtin_interfaces/Duration", _TIME),
    ),
)

#: ``geometry_msgs/msg/QuaternionStamped``: an orientation (x, y, z, w).
QUATERNION_STAMPED = (
    "geometry_msgs/msg/QuaternionStamped",
    definition(
        "std_msgs/Header header\ngeometry_msgs/Quaternion quaternion\n",
        *HEADER_TYPES,
        ("geometry_msgs/Quaternion", "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"),
    ),
)

#: ``rcl_interfaces/msg/Log``: what ROS 2 nodes publish on /rosout (Foxglove's Log panel).
LOG = (
    "rcl_interfaces/msg/Log",
    definition(
        "byte DEBUG=10\nbyte INFO=20\nbyte WARN=30\nbyte ERROR=40\nbyte FATAL=50\n"
        "builtin_interfaces/Time stamp\nuint8 level\nstring name\nstring msg\nstring file\n"
        "string function\nuint32 line\n",
        ("builtin_interfaces/Time", _TIME),
    ),
)

#: Log levels of ``rcl_interfaces/msg/Log``.
LOG_INFO, LOG_WARN, LOG_ERROR = 20, 30, 40


def time_msg(t_s: float) -> dict:
    """``builtin_interfaces/Time`` (or Duration) of ``t_s`` seconds, to the nanosecond."""
    ns = to_ns(t_s)
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def to_ns(t_s: float) -> int:
    """``t_s`` seconds as whole nanoseconds (an MCAP log time)."""
    if not math.isfinite(t_s):
        raise BadArgument(f"Expected a finite time, got {t_s} s.")
    return round(t_s * 1e9)


def header(t_s: float, frame_id: str = "") -> dict:
    """``std_msgs/Header`` stamped ``t_s`` seconds."""
    return {"stamp": time_msg(t_s), "frame_id": frame_id}


class McapMissing(ImportError):
    """The ``mcap`` extra is not installed."""


def _import_mcap():
    try:
        import mcap_ros2.writer
        from mcap.writer import CompressionType
    except ImportError as e:
        raise McapMissing(
            f"MCAP files need the mcap extra ({e}): pip install 'trajgen[mcap]'"
        ) from None
    return mcap_ros2.writer, CompressionType


def mcap_writer(output, *, chunk_size: int = 1024 * 1024):
    """An ``mcap_ros2.writer.Writer`` on ``output`` (a path or a binary file), zstd chunks.

    Parameters
    ----------
    output : str or Path or binary file
    chunk_size : int, optional
        Bytes of messages per chunk: a chunk reaches the file when it is full,
        so small chunks lose little when a process is killed.

    Raises
    ------
    McapMissing
        If ``mcap`` / ``mcap-ros2-support`` are not installed.
    """
    writer_module, compression = _import_mcap()
    if isinstance(output, Path):
        output = str(output)
    return writer_module.Writer(output, chunk_size=chunk_size, compression=compression.ZSTD)


@dataclass(frozen=True)
class Decoded:
    """One message read back.

    Attributes
    ----------
    topic : str
    sequence : int
        The MCAP message's sequence number.
    log_time_ns : int
    message : object
        The decoded ROS 2 message (fields as attributes).
    """

    topic: str
    sequence: int
    log_time_ns: int
    message: object


@dataclass
class McapContents:
    """What :func:`read_messages` found.

    Attributes
    ----------
    complete : bool
        False when the file ends before its DataEnd record (a writer killed
        before it finished): everything up to its last whole chunk was read.
    metadata : dict of str to dict
        Metadata records by name.
    """

    complete: bool = False
    metadata: dict | None = None


def read_messages(path, contents: McapContents | None = None) -> Iterator[Decoded]:
    """Every message of an MCAP file in file order, decoded, without seeking.

    Reads the file front to back (``mcap``'s non-seeking reader), so a file
    without its summary and footer (a writer killed mid-run) reads up to its
    last whole chunk.

    Parameters
    ----------
    path : str or Path
    contents : McapContents, optional
        Filled in when the iteration ends: whether the file was complete, and
        its metadata records.

    Yields
    ------
    Decoded

    Raises
    ------
    McapMissing
        If ``mcap`` / ``mcap-ros2-support`` are not installed.
    ValueError
        If the file is not MCAP.
    OSError
        If it cannot be read.
    """
    _import_mcap()
    from mcap.exceptions import EndOfFile, McapError
    from mcap.records import Channel, DataEnd, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader
    from mcap_ros2.decoder import DecoderFactory

    contents = McapContents() if contents is None else contents
    contents.metadata = {}
    contents.complete = False
    factory = DecoderFactory()
    schemas, channels, decoders = {}, {}, {}
    with open(path, "rb") as f:
        records = StreamReader(f).records
        try:
            for record in records:
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                    decoders[record.id] = factory.decoder_for(
                        record.message_encoding, schemas.get(record.schema_id)
                    )
                elif isinstance(record, Message):
                    decode = decoders[record.channel_id]
                    if decode is None:
                        continue  # not a ROS 2 message
                    yield Decoded(
                        channels[record.channel_id].topic,
                        record.sequence,
                        record.log_time,
                        decode(record.data),
                    )
                elif isinstance(record, Metadata):
                    contents.metadata[record.name] = dict(record.metadata)
                elif isinstance(record, DataEnd):
                    contents.complete = True
                    return  # the summary only repeats and indexes the data
        except (EndOfFile, struct.error):
            return  # cut short: read up to the last whole record
        except McapError as e:
            raise BadArgument(f"{path}: not a readable MCAP file ({e})") from None
