"""LTC from an audio input: PortAudio (sounddevice) blocks -> the decoder, in a thread of its own.

PortAudio's callback only stamps each block with the show time of its first sample (the
callback's time less the input latency PortAudio reports) and hands a copy of the one channel
to a bounded queue: a full queue drops the block and counts it, so a stalled decoder never
grows memory. Our thread takes the blocks, decodes them and puts the frames, stamped where
they ended, into the chase's inbox; the loop only polls the chase. Dropped blocks are said in
``ltc_audio_dropped`` (at most one event a second) and in the summary. Needs
``pip install 'hilsim[live]'`` (sounddevice, and the PortAudio library).
"""

from __future__ import annotations

import contextlib
import math
import queue
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from hilsim.live.inbox import LiveEvent
from hilsim.live.ltc import LtcDecoder

if TYPE_CHECKING:
    from hilsim.live.ltc_chase import LtcChase, LtcConfig

#: one block (s): PortAudio's callback size
BLOCK_S = 0.01
#: blocks the queue holds (0.32 s of audio) before it drops them
QUEUE_BLOCKS = 32


class AudioLtcReader:
    """One audio input feeding ``chase``; ``sd`` is the sounddevice module (tests: a fake)."""

    def __init__(
        self, chase: LtcChase, config: LtcConfig, now: Callable[[], float], *, sd: Any = None
    ) -> None:
        if sd is None:
            from hilsim.live.audio_out import require_sounddevice

            try:
                sd = require_sounddevice()
            except ValueError as exc:  # its message speaks of sounds
                msg = str(exc).replace("sounds need", "LTC from an audio input needs")
                raise ImportError(msg) from None
        self._sd, self._chase, self._cfg, self._now = sd, chase, config, now
        self._q: queue.Queue[tuple[float, Any] | None] = queue.Queue(maxsize=QUEUE_BLOCKS)
        self.dropped = 0  #: blocks dropped: the queue was full
        self.overflows = 0  #: blocks PortAudio flagged as overflowed (samples lost before us)
        self.errors = 0  #: blocks the decoder refused
        self._said_drops = 0
        self._drop_event_t = -math.inf
        self.rate = 0
        self._stream: Any = None
        self._thread: threading.Thread | None = None

    @property
    def device(self) -> Any:
        src = self._cfg.source
        return None if src == "default" else src

    def open(self) -> None:
        """Open and start the input stream and the decoder thread; raises on no device."""
        sd, cfg = self._sd, self._cfg
        rate = cfg.sample_rate
        if rate is None:
            info = sd.query_devices(self.device, "input")
            rate = round(float(info["default_samplerate"]))
        self.rate = int(rate)
        self._chase.decoder = LtcDecoder(self.rate)
        self._stream = sd.InputStream(
            device=self.device,
            channels=cfg.channel,
            samplerate=self.rate,
            dtype="float32",
            blocksize=max(1, round(BLOCK_S * self.rate)),
            callback=self._callback,
        )
        self._chase.latency_s = 2 * BLOCK_S + float(getattr(self._stream, "latency", 0.0) or 0.0)
        self._thread = threading.Thread(target=self._run, name="hilsim-ltc", daemon=True)
        self._thread.start()
        self._stream.start()

    def _callback(self, indata: Any, frames: int, time: Any, status: Any) -> None:
        """PortAudio's thread: stamp, copy one channel, hand over; never blocks."""
        t = self._now()
        lag = getattr(time, "currentTime", 0.0) - getattr(time, "inputBufferAdcTime", 0.0)
        if not 0.0 < lag < 1.0:  # not reported: the block ended as the callback came
            lag = frames / self.rate
        if getattr(status, "input_overflow", False):
            self.overflows += 1
        try:
            self._q.put_nowait((t - lag, indata[:, self._cfg.channel - 1].copy()))
        except queue.Full:
            self.dropped += 1

    def _run(self) -> None:
        while True:
            item = self._q.get()
            if item is None:
                return
            t_first, block = item
            try:
                self._chase.feed_samples(block, t_first)
            except ValueError:  # LtcError or a stamp out of order: this block is lost
                self.errors += 1
            finally:
                self._q.task_done()  # (a test joins the queue: every block decoded)

    def take_events(self, t: float) -> list[LiveEvent]:
        """The loop's: one ``ltc_audio_dropped`` a second at most while blocks are dropped."""
        new = self.dropped - self._said_drops
        if new <= 0 or t - self._drop_event_t < 1.0:
            return []
        self._said_drops, self._drop_event_t = self.dropped, t
        return [LiveEvent(t, "ltc_audio_dropped", self._chase.source, {
            "message": f"LTC: {new} audio blocks dropped (the decoder fell behind)",
            "dropped": new, "total": self.dropped})]  # fmt: skip

    def describe(self) -> str:
        cfg = self._cfg
        name = "the default input" if self.device is None else f"audio input {cfg.source!r}"
        return (
            f"LTC from {name} ({self.rate} Hz, channel {cfg.channel}), fps {cfg.fps}, "
            f"offset {cfg.offset_s:g} s"
        )

    def close(self) -> None:
        stream, self._stream = self._stream, None
        if stream is not None:
            try:
                stream.stop()
            finally:
                stream.close()
        if self._thread is not None:
            while True:  # make room for the end mark: the blocks left are not needed
                try:
                    self._q.put_nowait(None)
                    break
                except queue.Full:
                    with contextlib.suppress(queue.Empty):
                        self._q.get_nowait()
            self._thread.join(timeout=1.0)
            self._thread = None

    def summary(self) -> dict[str, Any]:
        return {"sample_rate": self.rate, "blocks_dropped": self.dropped,
                "input_overflows": self.overflows, "blocks_refused": self.errors}  # fmt: skip


def open_audio_input(
    chase: LtcChase, config: LtcConfig, now: Callable[[], float], *, sd: Any = None
) -> AudioLtcReader:
    """Open ``config``'s audio input for ``chase``; raises OSError/ValueError/RuntimeError
    (one line) when there is no such device or no sounddevice."""
    reader = AudioLtcReader(chase, config, now, sd=sd)
    try:
        reader.open()
    except Exception as exc:  # PortAudioError, ValueError (no such device): one line
        reader.close()
        raise OSError(str(exc).splitlines()[0] if str(exc) else type(exc).__name__) from None
    return reader
