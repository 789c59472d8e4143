"""Live inputs: timestamped messages in, the latest values and events out, on the loop's clock.

Every input is driven by messages stamped with show time (s, the loop's clock; tests inject them,
a receiver thread stamps them on arrival), and the loop calls a non-blocking ``poll(t)`` once per
tick: bounded work, never a wait. The optional packages (mido for
MIDI ports, sounddevice for sound) are imported lazily; a missing one is one clear line naming
the extra (``pip install 'hilsim[live]'``). OSC needs none: its decoder is our own.

============================  ===================================================================
module                        what it holds
============================  ===================================================================
``director.py``               the loop's per-tick hook: inputs polled, each joint's target (live,
                              clip, rig), events, the take, a stop command
``showfile.py``               the show file (``hilsim run --show``) and ``--live``'s built-in one
``show.py``                   ShowRuntime: idle layer, cues, timeline, the tracks they drive
``show_spec.py``              the show file's clips, sounds, idle, cues and timeline
``triggers.py``               trigger strings (osc:, midi:, key:, every:, at:, daily:), windows
``inbox.py``                  Inbox: the bounded receiver -> loop queue (drops the oldest,
                              counts the drops); LiveEvent: one event for ``events.jsonl``
``midi.py``                   MIDI control change -> joint degrees (7- or 14-bit), lost input,
                              note/CC triggers, a real port through mido (optional extra)
``timecode.py``               MIDI Time Code chase: quarter frames and full-frame SysEx ->
                              show time, freewheel then hold, jumps reported
``takes.py``                  record a take (raw (t, deg) per joint), reduce it to keyframes
                              within a tolerance, write raw/keys CSV and ``take.toml``
``osc.py``                    OSC over UDP (own strict OSC 1.0 decoder, no extra needed):
                              ``/hilsim/joint/<name>`` 0..1 -> degrees, ``/hilsim/cue/<name>``,
                              ``/hilsim/stop``; LiveTargets (latest target per joint, lost input)
``netguard.py``               network safety: loopback unless an interface is named, allow-list,
                              size and per-sender rate limits, drops counted by kind and logged
                              once a second per kind; UdpReceiver (a capped receiver thread)
``gamepad.py``                gamepad axes -> joint degrees, buttons -> triggers, unplugged ->
                              hold (pygame, optional extra: gamepad)
``keyboard.py``               keys typed in the terminal -> ``key:<k>`` triggers (cbreak,
                              restored on every way out)
``bottango_live.py``          Bottango's live driver protocol (+ ``bottango_link.py``: pty/TCP,
                              ``bottango_config.py``: ``[inputs.bottango]``)
``audio_out.py``              sounds in sync with clips (latency and offset compensated,
                              preloaded), sounddevice backend (optional extra: live), silent
============================  ===================================================================

User documentation: ``docs/live.md``.
"""
