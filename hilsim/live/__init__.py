"""Live inputs: timestamped messages in, the latest values and events out, on the loop's clock.

Every input is driven by messages stamped with show time (s, the loop's clock). A receiver
thread stamps them on arrival; tests inject them. The loop calls a non-blocking ``poll(t)``
once per tick: bounded work, never a wait. The optional packages (mido for MIDI, pygame for a
gamepad, sounddevice for sound) are imported lazily. A missing one is one clear line naming
the extra (``pip install 'hilsim[live]'``). OSC needs none: its decoder is our own.

The show: :mod:`~hilsim.live.director` (the loop's per-tick hook), :mod:`~hilsim.live.showfile`,
:mod:`~hilsim.live.show_spec`, :mod:`~hilsim.live.show`, :mod:`~hilsim.live.triggers`. The
inputs: :mod:`~hilsim.live.osc` (+ :mod:`~hilsim.live.netguard`), :mod:`~hilsim.live.midi`,
:mod:`~hilsim.live.timecode`, :mod:`~hilsim.live.gamepad`, :mod:`~hilsim.live.keyboard`,
:mod:`~hilsim.live.bottango_live`. Sound and takes: :mod:`~hilsim.live.audio_out`,
:mod:`~hilsim.live.takes`, :mod:`~hilsim.live.teach`.

User documentation, and a table of the modules: ``docs/live.md``.
"""
