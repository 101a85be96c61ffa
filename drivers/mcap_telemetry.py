"""The MCAP run log: telemetry rows written as ROS 2 messages off the streaming path.

The stream's thread only puts each row on a queue; a sender thread pipes the
rows to a writer process, which encodes them
(``trajgen.telemetry_mcap.RowMessages``: goal, present and planned
``sensor_msgs/msg/JointState`` and the frame's bookkeeping) and writes them in
small zstd chunks (:data:`CHUNK_BYTES`), flushing the file whenever its pipe
is empty. A chunk reaches the disk when it is full, so a run killed outright
(SIGKILL of the process group) leaves a file readable, front to back, up to
its last whole chunk (``trajgen.ros2_messages.read_messages``); any other stop
finishes the file (summary, index, footer).

After the stream, :func:`add_report` adds the run's report (a metadata record
``trajgen.report``) and its faults and stop reason as ``rcl_interfaces/msg/Log``
on ``/rosout`` (Foxglove's Log panel), by copying the file once.

Imports ``mcap`` (the ``mcap`` extra); ``trajgen.drivers.telemetry`` loads this
module only for a ``.mcap`` path.
"""

from __future__ import annotations

import io
import json
import os
import pickle
import queue
import struct
import subprocess
import sys
import threading
from collections.abc import Sequence
from pathlib import Path

from trajgen.ros2_messages import (
    JOINT_STATE,
    LOG,
    LOG_ERROR,
    LOG_INFO,
    LOG_WARN,
    McapMissing,
    mcap_writer,
    time_msg,
)
from trajgen.telemetry_mcap import (
    FRAME,
    GOAL,
    METADATA_NAME,
    PLAN,
    PRESENT,
    STREAM_FRAME,
    RowMessages,
)

#: Bytes of messages per chunk while streaming: about 20 frames of three joints.
CHUNK_BYTES = 16 * 1024

#: Topic and node name of the run's log messages.
ROSOUT, NODE = "/rosout", "trajgen"

#: Name of the metadata record holding the run's report.
REPORT_NAME = "trajgen.report"


class McapRunLog:
    """Telemetry rows to an MCAP file, encoded and written by a process of its own.

    The stream's thread only queues each row; a sender thread pickles the
    queued rows down a pipe to a writer process (``python -m
    trajgen.drivers.mcap_telemetry``, in a session of its own), which encodes
    and writes them: the encoding (pure Python, about 0.4 ms a message here)
    never holds the streaming process's GIL. The writer process finishes the
    file when its pipe closes, so it outlives a stream process killed outright
    and still finishes the file; stop signals to the terminal's process group
    do not reach it (the stream stops safely, then closes the log).

    Parameters
    ----------
    path : str or Path
        The ``.mcap`` file. The writer process starts in the background (its
        imports take a while): rows queue until it is up, so the stream does
        not wait, and a file that cannot be created fails the next ``write``
        or ``close``.
    columns : sequence of str
        The telemetry columns (``trajgen.drivers.telemetry.telemetry_columns``).
    joint_names : sequence of str
    effort_nm_per_a : sequence of float, optional
        Each joint's torque constant (N m/A), for the effort of ``/trajgen/present``.
    current_scale : sequence of str, optional
        Each joint's current register scale, stated in the metadata.
    chunk_size : int, optional
        Bytes per chunk.

    Raises
    ------
    ValueError
        If a column has no place in the layout.
    """

    def __init__(
        self,
        path: str | Path,
        columns: Sequence[str],
        joint_names: Sequence[str],
        effort_nm_per_a: Sequence[float] | None = None,
        current_scale: Sequence[str] | None = None,
        *,
        chunk_size: int = CHUNK_BYTES,
    ) -> None:
        scales = (effort_nm_per_a, current_scale)
        RowMessages(columns, joint_names, *scales)  # bad columns fail here
        self._process = subprocess.Popen(
            [sys.executable, "-m", __name__],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            start_new_session=True,
        )
        layout = (str(path), list(columns), list(joint_names), scales, chunk_size)
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._queue.put(layout)
        self._error: BaseException | None = None
        self._sender = threading.Thread(target=self._send, name="mcap telemetry", daemon=True)
        self._sender.start()

    def write(self, row: Sequence) -> None:
        """Queue one row (the stream's thread: no encoding, no I/O).

        Raises
        ------
        OSError, McapMissing
            If the writer process failed (the file cannot be created, the disk
            is full, no ``mcap`` extra).
        """
        if self._error is not None:
            raise self._error
        self._queue.put(row)

    def close(self) -> None:
        """Write what is queued, finish the file (summary and footer) and wait for it.

        Raises
        ------
        OSError, McapMissing
            If the writer process failed.
        """
        if self._process is None:
            return
        self._queue.put(None)
        self._sender.join()
        if self._error is None:
            kind, detail = _status(self._process.stdout)
            if kind != "done":
                self._error = _error(kind, detail)
        self._process.stdout.close()
        self._process.wait()
        self._process = None
        if self._error is not None:
            raise self._error

    def _send(self) -> None:
        pipe = self._process.stdin
        try:
            pickle.dump(self._queue.get(), pipe)
            while True:
                rows = [self._queue.get()]
                while not self._queue.empty():
                    rows.append(self._queue.get())
                last = rows[-1] is None
                pickle.dump(rows[:-1] if last else rows, pipe)
                pipe.flush()
                if last:
                    break
        except OSError:  # the writer process is gone: its status tells why
            self._error = _error(*_status(self._process.stdout))
        finally:
            try:
                pipe.close()
            except OSError:
                pass


def _status(pipe) -> tuple[str, str]:
    """The writer process's last status: ("done", "") or (exception name, message)."""
    status = ("OSError", "the MCAP writer process ended without finishing the file")
    try:
        while True:
            status = pickle.load(pipe)
    except (EOFError, pickle.UnpicklingError):
        return status


def _error(kind: str, detail: str) -> BaseException:
    """The exception the writer process reported."""
    return (McapMissing if kind == "McapMissing" else OSError)(detail)


def _write_rows(rows, status) -> None:
    """The writer process: a layout, then lists of rows from ``rows`` (EOF ends) to MCAP.

    Statuses go to ``status``: ``("ready", "")``, then ``("done", "")`` or the
    failure as ``(exception name, message)``.
    """
    path, columns, joint_names, scales, chunk_size = pickle.load(rows)

    def report(kind: str, detail: str = "") -> None:
        try:
            pickle.dump((kind, detail), status)
            status.flush()
        except OSError:  # the stream process is gone: nobody to tell
            pass

    try:
        layout = RowMessages(columns, joint_names, *scales)
        file = open(path, "wb")  # noqa: SIM115 (closed below)
    except (OSError, ValueError) as e:
        return report("OSError", f"telemetry {path}: {e}")
    failure = None
    try:
        writer = mcap_writer(file, chunk_size=chunk_size)
        state = writer.register_msgdef(*JOINT_STATE)
        schemas = {GOAL: state, PRESENT: state, PLAN: state}
        schemas[FRAME] = writer.register_msgdef(*STREAM_FRAME)
        writer.add_metadata(METADATA_NAME, layout.metadata())
        file.flush()
        report("ready")
        while True:
            try:
                batch = pickle.load(rows)
            except (EOFError, pickle.UnpicklingError):  # the pipe closed (a stream killed)
                break
            for row in batch:
                for topic, message, log_time, sequence in layout.messages(row):
                    writer.write_message(
                        topic, schemas[topic], message, log_time, sequence=sequence
                    )
            file.flush()
        writer.finish()
    except McapMissing as e:
        failure = ("McapMissing", str(e))
    except Exception as e:  # noqa: BLE001 (reported to the stream, which raises it)
        failure = ("OSError", f"telemetry {path}: {type(e).__name__}: {e}")
    finally:
        file.close()
    report(*(failure or ("done",)))


def report_log(report: dict) -> list[tuple[int, str]]:
    """The faults and the stop reason of a run's report, as ``(level, text)``."""
    stream = report.get("stream") or {}
    lines: list[tuple[int, str]] = []
    if stream.get("read_fallback"):
        lines.append((LOG_WARN, f"read back by sync read: {stream['read_fallback']}"))
    if stream.get("stalls"):
        lines.append(
            (
                LOG_WARN,
                f"{stream['stalls']} stalls; the stream ended {stream['delay_s']:.6f} s "
                "behind its plan",
            )
        )
    if stream.get("comm_errors"):
        lines.append((LOG_WARN, f"{stream['comm_errors']} failed transactions (retried or fatal)"))
    lines += [(LOG_ERROR, f"safe stop: {e}") for e in report.get("stop_errors", ())]
    planned = stream.get("frames_planned") or 0  # 0: an online stream, length unknown
    sent = f"{stream.get('frames_sent', 0)}{f'/{planned}' if planned else ''} frames sent"
    if report.get("stopped_by"):
        lines.append((LOG_ERROR, f"stopped by: {report['stopped_by']} ({sent})"))
    else:
        lines.append((LOG_INFO, f"stream completed: {sent}"))
    torque = report.get("torque")
    if isinstance(torque, dict) and "ok" in torque:
        level = LOG_INFO if torque["ok"] else LOG_ERROR
        lines.append((level, f"torque check {'passed' if torque['ok'] else 'failed'}"))
    lines.append((LOG_INFO, f"exit status {report.get('status')}; servos: {report.get('on_stop')}"))
    return lines


def add_report(path: str | Path, report: dict, progress=None) -> None:
    """Add a run's report and its log to a finished MCAP run log (the file is copied once).

    The report becomes the metadata record ``trajgen.report`` (one entry per
    top-level key, its value as JSON); :func:`report_log` becomes
    ``rcl_interfaces/msg/Log`` messages on ``/rosout``, stamped at the last
    frame. The copy replaces the file only when complete.

    Parameters
    ----------
    path : str or Path
    report : dict
        The run's report (``trajgen stream --json``'s content).
    progress : callable, optional
        Called with the fraction of the file copied (0..1), now and then.

    Raises
    ------
    OSError
        If the file cannot be read or written.
    """
    from mcap.exceptions import EndOfFile
    from mcap.records import Attachment, Channel, DataEnd, Header, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import Writer

    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    size = max(path.stat().st_size, 1)
    end_ns = 0
    try:
        with open(path, "rb") as src, open(tmp, "wb") as out:
            copy = Writer(out)
            try:
                for k, record in enumerate(StreamReader(src).records):
                    if progress is not None and k % 20_000 == 0:
                        progress(src.tell() / size)
                    if isinstance(record, Header):
                        copy.start(record.profile, record.library)
                    elif isinstance(record, Schema):
                        copy.register_schema(record.name, record.encoding, record.data)
                    elif isinstance(record, Channel):
                        copy.register_channel(
                            record.topic,
                            record.message_encoding,
                            record.schema_id,
                            record.metadata,
                        )
                    elif isinstance(record, Message):
                        copy.add_message(
                            record.channel_id,
                            record.log_time,
                            record.data,
                            record.publish_time,
                            record.sequence,
                        )
                        end_ns = max(end_ns, record.log_time)
                    elif isinstance(record, Metadata):
                        copy.add_metadata(record.name, record.metadata)
                    elif isinstance(record, Attachment):
                        copy.add_attachment(
                            record.create_time,
                            record.log_time,
                            record.name,
                            record.media_type,
                            record.data,
                        )
                    elif isinstance(record, DataEnd):
                        break  # the summary repeats schemas and channels
            except (EndOfFile, struct.error):
                pass  # a file cut short: copy what it holds
            schema = copy.register_schema(LOG[0], "ros2msg", LOG[1].encode())
            channel = copy.register_channel(ROSOUT, "cdr", schema)
            stamp = time_msg(end_ns * 1e-9)
            logs = [
                {"stamp": stamp, "level": level, "name": NODE, "msg": text}
                | {"file": "", "function": "", "line": 0}
                for level, text in report_log(report)
            ]
            for data in _encode(LOG, logs):
                copy.add_message(channel, end_ns, data, end_ns)
            copy.add_metadata(REPORT_NAME, {k: json.dumps(v) for k, v in report.items()})
            copy.finish()
        os.replace(tmp, path)
        if progress is not None:
            progress(1.0)
    finally:
        if tmp.exists():
            tmp.unlink()


def _encode(msgdef: tuple[str, str], messages: list[dict]) -> list[bytes]:
    """CDR bytes of ROS 2 messages (encoded by ``mcap_ros2`` into a scratch MCAP)."""
    from mcap.records import Message
    from mcap.stream_reader import StreamReader

    scratch = io.BytesIO()
    writer = mcap_writer(scratch)
    schema = writer.register_msgdef(*msgdef)
    for message in messages:
        writer.write_message("/scratch", schema, message, log_time=0)
    writer.finish()
    scratch.seek(0)
    return [r.data for r in StreamReader(scratch).records if isinstance(r, Message)]


if __name__ == "__main__":
    _write_rows(sys.stdin.buffer, sys.stdout.buffer)
