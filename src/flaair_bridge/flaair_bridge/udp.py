"""A bound UDP socket read by a dedicated thread: each datagram is handed to a callback at once.

rclpy's EventsExecutor has no guard conditions, and polling the socket from a timer would add
up to the timer's period to the loop latency; a thread blocked in recvmsg costs nothing while
idle and releases the GIL. Each datagram carries the kernel's receive time (SO_TIMESTAMPNS,
wall clock, `time.time()` seconds): when the reader falls behind, a datagram's arrival is still
known, so the bridge knows how far the target's clock has moved on.
"""

from __future__ import annotations

import select
import socket
import struct
import threading
import time
from collections.abc import Callable

from flaair_common.realtime import take_realtime_priority

SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)  # Linux; Python does not name it
_TIMESPEC = struct.Struct("@qq")


class DatagramEndpoint:
    """UDP socket bound to (host, port); once started, `on_datagram(data, sender, arrival_s)`
    runs in the reader thread (arrival_s: kernel receive time on the `time.time()` clock).
    """

    def __init__(
        self,
        host: str,
        port: int,
        receive_buffer_bytes: int,
        on_datagram: Callable[[bytes, tuple[str, int], float], None],
        realtime_priority: int = 0,
    ) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer_bytes)
            self.sock.bind((host, port))
            self.sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        except OSError:
            self.sock.close()
            raise
        self.sock.settimeout(0.1)  # the reader checks for close() this often
        self.on_datagram = on_datagram
        self.realtime_priority = realtime_priority
        # why the reader could not take its real-time priority ("" if it did, or none asked)
        self.priority_error = ""
        self.priority_set = threading.Event()
        self.running = True
        self.reader = threading.Thread(target=self._read, name=f"udp-{host}:{port}", daemon=True)

    def start(self) -> None:
        """Start the reader thread: datagrams reach `on_datagram` from now on (its owner holds
        this endpoint already, so an answer sent from inside the callback has a socket to go by).
        """
        self.reader.start()

    def _read(self) -> None:
        # SCHED_FIFO: a datagram preempts the other processes at once, instead of waiting out
        # their time slice while the socket fills
        self.priority_error = take_realtime_priority(self.realtime_priority)
        self.priority_set.set()
        while self.running:
            try:
                data, ancillary, _flags, sender = self.sock.recvmsg(
                    65536, socket.CMSG_SPACE(_TIMESPEC.size)
                )
            except TimeoutError:
                continue
            except OSError:
                if not self.running:
                    return
                continue  # e.g. ICMP port unreachable from an earlier send: keep reading
            arrival_s = time.time()
            for level, kind, value in ancillary:
                if (
                    level == socket.SOL_SOCKET
                    and kind == SO_TIMESTAMPNS
                    and len(value) >= _TIMESPEC.size
                ):
                    seconds, nanoseconds = _TIMESPEC.unpack_from(value)
                    arrival_s = seconds + 1e-9 * nanoseconds
            self.on_datagram(data, sender, arrival_s)

    def pending(self) -> bool:
        """Datagrams are queued, not read yet (the reader
        thread is behind: this process stalled).
        """
        try:
            return bool(select.select([self.sock], [], [], 0.0)[0])
        except (OSError, ValueError):
            return False

    def send(self, packet: bytes, address: tuple[str, int]) -> str:
        """Send one datagram; returns '' or the OS error's
        text (UDP: the peer will notice the silence).
        """
        try:
            self.sock.sendto(packet, address)
            return ""
        except OSError as exc:
            return str(exc)

    def stop_reading(self) -> None:
        """Stop the reader thread (after the datagram it is handling); the socket still sends."""
        self.running = False
        if self.reader.is_alive() and self.reader is not threading.current_thread():
            self.reader.join(timeout=1.0)

    def close(self) -> None:
        """Stop the reader thread and close the socket."""
        self.stop_reading()
        self.sock.close()
