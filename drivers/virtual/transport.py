"""The virtual bus's pseudo-terminal side: reading packets, writing replies with wire timing.

``WireTiming`` adds what a pty lacks (byte time, Return Delay Time, servo
turnaround, adapter latency); ``PtyTransport`` (a part of ``VirtualBus``)
serves the pty master, from a thread or in the thread of a client in the same
process (lock-step), and hands each packet to ``_handle``.
"""

from __future__ import annotations

import heapq
import os
import select
import time
from dataclasses import dataclass

from trajgen.servo_table import TURNAROUND_S

from ..control_table import RETURN_DELAY_UNIT_S
from ..defaults import DEFAULT_BAUD

# How long ``answer`` waits for bytes a client wrote to come through the pty (s):
# the kernel passes them on at once; this only bounds a lost write.
_ARRIVAL_WAIT_S = 5.0
# Most bytes read from the pty at once (a packet is at most a few hundred).
_READ_BYTES = 1 << 12


@dataclass(frozen=True)
class WireTiming:
    """Timing of a real bus, added by the emulator.

    Attributes
    ----------
    baud : int
        Bit rate (bit/s); a byte takes 10 bits.
    adapter_latency_s : float
        Delay (s) from a reply's last byte on the wire to the host reading it
        (USB adapter; a U2D2 at latency timer 1 ms is about 1e-3).
    turnaround_s : float
        Servo processing time (s) before its Return Delay Time starts.
    """

    baud: int = DEFAULT_BAUD
    adapter_latency_s: float = 0.0
    turnaround_s: float = TURNAROUND_S

    @property
    def byte_time_s(self) -> float:
        """Time (s) one byte takes on the wire."""
        return 10.0 / self.baud


class PtyTransport:
    """Serving a ``VirtualBus``'s pty master (its ``_master``, ``lock``, ``_handle``).

    Two ways: a thread that answers whatever arrives (any client, any
    process), or, for a client in this process attached with
    ``attach_client`` (lock-step only), ``answer`` called by the client right
    after each write, which answers in the client's own thread before the
    client starts waiting for a reply: no thread has to be scheduled in time,
    so no reply timeout can expire on a busy host.
    """

    def _serve(self) -> None:
        while not self._stop.is_set():
            with self._io_lock:
                self._flush_late_replies()
            wait_s = 0.05
            if self._late:
                wait_s = min(wait_s, max(0.0, self._late[0][0] - time.monotonic()))
            if self._client_answers:  # the client answers its own packets
                self._stop.wait(wait_s)
                continue
            watched = [self._master]
            if self._process is not None:  # the plant in its own process: it may fail
                watched.append(self._process)
                wait_s = min(wait_s, self._watch_watchdogs())
            try:
                self._serving_idle = True  # waiting for the host (see _simulate)
                ready, _, _ = select.select(watched, [], [], wait_s)
                self._serving_idle = False
            except (OSError, ValueError):
                return  # master closed
            if self._process is not None and self._process in ready:
                try:
                    self._process.check()
                except Exception as e:  # the plant failed: the port goes away
                    self._fail(e)
                    return
            if self._master not in ready:
                continue
            with self._io_lock:
                if self._client_answers:
                    continue
                data = self._read_master()
                if data is None or self._answer_data(data, time.monotonic()) is None:
                    return

    def attach_client(self) -> None:
        """From now on, the client in this process answers its packets with ``answer``.

        Raises
        ------
        RuntimeError
            In real time (the simulation runs on the wall clock; a thread serves).
        """
        if self.lockstep_dt_s is None:
            raise RuntimeError("a real-time virtual bus is served by its own thread")
        with self._io_lock:
            self._client_answers = True

    def detach_client(self) -> None:
        """Back to the serving thread (the client closed)."""
        with self._io_lock:
            self._client_answers = False

    def answer(self, n_bytes: int) -> int:
        """Answer the ``n_bytes`` an attached client just wrote, in the caller's thread.

        Waits (up to ``_ARRIVAL_WAIT_S``, for the kernel to pass the bytes
        through the pty) until they have all arrived, handles every whole
        packet and writes its replies with their wire timing.

        Returns
        -------
        int
            Bytes of the replies written: they are on their way to the client,
            which may wait for them without a reply timeout. Replies a "delay"
            fault holds back are not counted (they come later, from the thread).
        """
        got = sent = 0
        with self._io_lock:
            deadline = time.monotonic() + _ARRIVAL_WAIT_S
            while got < n_bytes and self._master >= 0:
                try:
                    ready, _, _ = select.select(
                        [self._master], [], [], max(0.0, deadline - time.monotonic())
                    )
                except (OSError, ValueError):
                    break
                if not ready:
                    break  # never arrived: the client times out as it would on a wire
                data = self._read_master()
                if data is None:
                    break
                got += len(data)
                out = self._answer_data(data, time.monotonic())
                if out is None:
                    break
                sent += out
        return sent

    def _read_master(self) -> bytes | None:
        """What the master holds (b"" if nothing), or None if it is closed.

        Bytes read came in after the previous read started (``_arrived_after_s``).
        """
        started = time.monotonic()
        try:
            data = os.read(self._master, _READ_BYTES)
        except BlockingIOError:
            data = b""
        except (OSError, ValueError):
            return None
        if data:
            self._arrived_after_s = self._read_started_s
        self._read_started_s = started
        return data

    def _answer_data(self, data: bytes, arrival_s: float) -> int | None:
        """Answer the whole packets ``data`` completes; reply bytes written, None if closed."""
        self.bytes_received += len(data)
        self._reader.feed(data)
        sent = 0
        for raw in self._reader.packets():
            try:
                self._lock_wanted = True  # the simulation thread lets it go first
                with self.lock:
                    self._lock_wanted = False
                    replies = self._handle(raw, arrival_s)
            except Exception as e:  # the plant failed: the port goes away
                self._fail(e)
                return None
            if replies is None:  # "close" fault
                os.close(self._master)
                self._master = -1
                return None
            sent += self._send(raw, replies, arrival_s)
        return sent

    def _write(self, reply: bytes) -> int:
        try:
            os.write(self._master, reply)
        except OSError:
            return 0  # the host closed the port
        self.bytes_sent += len(reply)
        return len(reply)

    def _flush_late_replies(self) -> None:
        """Write the replies a "delay" fault held back, once they are due (io lock held)."""
        while self._late and self._late[0][0] <= time.monotonic():
            self._write(heapq.heappop(self._late)[2])

    def _send(
        self, request: bytes, replies: list[tuple[int, bytes, float, float]], arrival_s: float
    ) -> int:
        """Write replies [(servo id, bytes, extra delay, late on the wire)] with wire timing;
        bytes written now.

        Wire time is slept (the bus is busy); a "delay" fault's extra delay is
        not (the servo has acted on the packet, only its reply is late, off the
        wire). A "late" fault's is: the servo starts its reply that much later
        (s). While a reply is on the wire the master is watched: a host packet
        arriving then collides with it (``_collide``). That window is timed
        from the earliest the request can have come in (``_arrived_after_s``:
        this thread may have read it late, a busy host), so that only a packet
        surely on the wire with the reply counts.
        """
        t = arrival_s
        if self.timing is not None:
            byte_s = self.timing.byte_time_s
            t = max(arrival_s, self._wire_free_s) + len(request) * byte_s
            t_min = max(self._arrived_after_s, self._wire_free_min_s) + len(request) * byte_s
        self.wire_log.append((arrival_s, self._reply_end_s))
        sent = 0
        for servo_id, reply, extra_s, late_s in replies:
            if self.timing is not None:
                servo = self.servos.get(servo_id)
                delay = RETURN_DELAY_UNIT_S * servo.get("Return Delay Time") if servo else 0.0
                on_wire_s = self.timing.turnaround_s + delay + late_s + len(reply) * byte_s
                t, t_min = t + on_wire_s, t_min + on_wire_s
                if self._host_bytes_before(t_min):
                    reply = self._collide(reply, t_min)
                self._reply_end_s = t_min
                # Slept, not spun: a spin here would hold a core the host needs (2 cores).
                time.sleep(max(0.0, t + self.timing.adapter_latency_s - time.monotonic()))
            if extra_s:
                self._late_count += 1
                heapq.heappush(self._late, (time.monotonic() + extra_s, self._late_count, reply))
            else:
                sent += self._write(reply)
        self._wire_free_s = t
        if self.timing is not None:
            self._wire_free_min_s = t_min
        return sent

    def _host_bytes_before(self, end_s: float) -> bool:
        """Whether host bytes surely arrived at the master before ``end_s`` (``time.monotonic``,
        s; io lock held): they were on the wire with a reply that ends then.

        Only bytes seen readable by a ``select`` that returned before ``end_s``
        count: this thread may enter the ``select`` late (a busy host).
        """
        while True:
            left = end_s - time.monotonic()
            if left <= 0:
                return False
            try:
                ready = select.select([self._master], [], [], left)[0]
            except (OSError, ValueError):
                return False  # closed: nothing more arrives
            if ready:
                return time.monotonic() < end_s

    def _collide(self, reply: bytes, end_s: float) -> bytes:
        """A host packet came in over ``reply``: on a half-duplex bus both are garbled.

        The host's bytes (whatever of them is in) are dropped, as the servos'
        CRC check drops a garbled packet (a rest arriving later has no header:
        dropped too); the reply goes out with its CRC broken. Counted in
        ``collisions``, logged in ``wire_log`` (arrival, the reply's end ``end_s``).
        """
        self.collisions += 1
        arrival_s = time.monotonic()
        data = self._read_master() or b""
        self.bytes_received += len(data)
        self.wire_log.append((arrival_s, end_s))
        return reply[:-1] + bytes([reply[-1] ^ 0xFF])
