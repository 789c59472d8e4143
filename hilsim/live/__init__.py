"""Live inputs: timestamped messages in, the latest values and events out, on the loop's clock.

Every input is driven by messages stamped with show time (s, the loop's clock; tests inject them,
a receiver thread stamps them on arrival), and the loop calls a non-blocking ``poll(t)`` once per
tick: bounded work, never a wait. The optional packages (mido for
MIDI ports, sounddevice for sound) are imported lazily; a missing one is one clear line naming
the extra (``pip install 'hilsim[live]'``). OSC needs none: its decoder is our own.

============================  ===================================================================
module                        what it holds
============================  ===================================================================
``inbox.py``                  Inbox: the bounded receiver -> loop queue (drops the oldest,
                              counts the drops); LiveEvent: one event for ``events.jsonl``
``midi.py``                   MIDI control change -> joint degrees (7- or 14-bit), lost input,
                              a real port through mido (optional extra)
``timecode.py``               MIDI Time Code chase: quarter frames and full-frame SysEx ->
                              show time, freewheel then hold, jumps reported
``takes.py``                  record a take (raw (t, deg) per joint), reduce it to keyframes
                              within a tolerance, write a CSV track or ``[[t, deg], ...]`` keys
``osc.py``                    OSC over UDP (own strict OSC 1.0 decoder, no extra needed):
                              ``/hilsim/joint/<name>`` 0..1 -> degrees, ``/hilsim/cue/<name>``,
                              ``/hilsim/stop``; LiveTargets (latest target per joint, lost input)
``netguard.py``               network safety: loopback unless an interface is named, allow-list,
                              size and per-sender rate limits, drops counted by kind and logged
                              once a second per kind; UdpReceiver (a capped receiver thread)
============================  ===================================================================
"""
