"""The virtual bus's pseudo-terminal side: reading packets, writing replies with wire timing.

``WireTiming`` adds what a pty lacks (byte time, Return Delay Time, servo
turnaround, adapter latency); ``PtyTransport`` (a part of ``VirtualBus``)
serves the pty master from a thread and hands each packet to ``_handle``.
"""

from __future__ import annotations

import heapq
import os
import select
import time
from dataclasses import dataclass

from trajgen.drivers.clock import sleep_until
from trajgen.drivers.protocol import (
    PacketReader,
)


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

    baud: int = 1_000_000
    adapter_latency_s: float = 0.0
    turnaround_s: float = 20e-6

    @property
    def byte_time_s(self) -> float:
        """Time (s) one byte takes on the wire."""
        return 10.0 / self.baud


class PtyTransport:
    """Serving a ``VirtualBus``'s pty master (its ``_master``, ``lock``, ``_handle``)."""

    def _serve(self) -> None:
        reader = PacketReader()
        while not self._stop.is_set():
            self._flush_late_replies()
            wait_s = 0.05
            if self._late:
                wait_s = min(wait_s, max(0.0, self._late[0][0] - time.monotonic()))
            try:
                ready, _, _ = select.select([self._master], [], [], wait_s)
                if not ready:
                    continue
                data = os.read(self._master, 4096)
            except (OSError, ValueError):
                return  # master closed
            arrival_s = time.monotonic()
            self.bytes_received += len(data)
            reader.feed(data)
            for raw in reader.packets():
                try:
                    with self.lock:
                        replies = self._handle(raw, arrival_s)
                except Exception as e:  # the plant failed: the port goes away
                    self._fail(e)
                    return
                if replies is None:  # "close" fault
                    os.close(self._master)
                    self._master = -1
                    return
                self._send(raw, replies, arrival_s)

    def _write(self, reply: bytes) -> None:
        try:
            os.write(self._master, reply)
            self.bytes_sent += len(reply)
        except OSError:
            pass  # the host closed the port

    def _flush_late_replies(self) -> None:
        """Write the replies a "delay" fault held back, once they are due."""
        while self._late and self._late[0][0] <= time.monotonic():
            self._write(heapq.heappop(self._late)[2])

    def _send(self, request: bytes, replies: list[tuple[int, bytes, float]], arrival_s: float):
        """Write replies [(servo id, bytes, extra delay)] with wire timing.

        Wire time is slept (the bus is busy); a fault's extra delay is not (the
        servo has acted on the packet, only its reply is late).
        """
        t = arrival_s
        if self.timing is not None:
            t = max(arrival_s, self._wire_free_s) + len(request) * self.timing.byte_time_s
        for servo_id, reply, extra_s in replies:
            if self.timing is not None:
                servo = self.servos.get(servo_id)
                delay = 2e-6 * servo.get("Return Delay Time") if servo else 0.0
                t += self.timing.turnaround_s + delay + len(reply) * self.timing.byte_time_s
                sleep_until(t + self.timing.adapter_latency_s)
            if extra_s:
                self._late_count += 1
                heapq.heappush(self._late, (time.monotonic() + extra_s, self._late_count, reply))
            else:
                self._write(reply)
        self._wire_free_s = t
