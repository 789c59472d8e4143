"""A serial stand-in for driver tests: canned reply bytes on a virtual clock."""

from __future__ import annotations

#: Sync Read and Fast Sync Read instruction bytes
SYNC_READS = (0x82, 0x8A)


class CannedPort:
    """Answers each request with ``reply`` (only (Fast) Sync Reads, unless ``every_request``)
    and lets the virtual clock jump to the timeout when the reply is short. Install it as
    ``bus.link.port.ser`` after the bus is open."""

    def __init__(self, clock, reply: bytes, *, every_request: bool = False) -> None:
        self.clock, self.reply, self.pending, self.timeout = clock, reply, b"", 0
        self.every_request = every_request

    def write(self, data) -> int:
        answered = self.every_request or data[7] in SYNC_READS
        self.pending = self.reply if answered else b""
        return len(data)

    def read(self, n: int) -> bytes:
        out, self.pending = self.pending[:n], self.pending[n:]
        if len(out) < n and self.timeout:
            self.clock.advance(self.timeout)
        return out

    def reset_input_buffer(self) -> None:
        pass

    def close(self) -> None:
        pass
