"""A bound UDP socket read by a dedicated thread: each datagram is handed to a callback at once.

rclpy's EventsExecutor has no guard conditions, and polling the socket from a timer would add
up to the timer's period to the loop latency; a thread blocked in recvfrom costs nothing while
idle and releases the GIL.
"""
from __future__ import annotations

import socket
import threading
import time
from typing import Callable


class DatagramEndpoint:
    """UDP socket bound to (host, port); `on_datagram(data, sender, arrival_s)` runs in the reader thread."""

    def __init__(self, host: str, port: int, receive_buffer_bytes: int,
                 on_datagram: Callable[[bytes, tuple[str, int], float], None]) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer_bytes)
            self.sock.bind((host, port))
        except OSError:
            self.sock.close()
            raise
        self.sock.settimeout(0.1)  # the reader checks for close() this often
        self.on_datagram = on_datagram
        self.running = True
        self.reader = threading.Thread(target=self._read, name=f"udp-{host}:{port}", daemon=True)
        self.reader.start()

    def _read(self) -> None:
        while self.running:
            try:
                data, sender = self.sock.recvfrom(65536)
            except socket.timeout:
                continue
            except OSError:
                if not self.running:
                    return
                continue  # e.g. ICMP port unreachable from an earlier send: keep reading
            self.on_datagram(data, sender, time.monotonic())

    def send(self, packet: bytes, address: tuple[str, int]) -> str:
        """Send one datagram; returns '' or the OS error's text (UDP: the peer will notice the silence)."""
        try:
            self.sock.sendto(packet, address)
            return ""
        except OSError as exc:
            return str(exc)

    def close(self) -> None:
        """Stop the reader thread and close the socket."""
        self.running = False
        if self.reader is not threading.current_thread():
            self.reader.join(timeout=1.0)
        self.sock.close()
