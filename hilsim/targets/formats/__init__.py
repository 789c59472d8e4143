"""Readers of other tools' animation files, each to tracks in joint radians.

======================  ===============================================================
``common``              :class:`FormatError`, :class:`UnitMap`, :class:`SampledTrack`
``bottango``            Bottango exports (generated code, SD card, JSON) -> Bézier tracks;
                        ``bottango_forms`` finds the commands in each form,
                        ``bottango_curve`` the exact Bézier segment and track
``blender_servo``       blender-servo-animation ``.json``/``.bin``/``.h`` (parsers in
                        ``blender_servo_forms``)
``fseq``                xLights/FPP ``.fseq`` v2 (plain, zstd, zlib, sparse) and v1; 8/16-bit
``audio_jaw``           a sound file through an envelope follower -> a jaw track;
                        ``spring_lag_s``, the lead that puts the commanded jaw in time
``lipsync``             Rhubarb (``lipsync_cues``), Moho ``.dat``, Papagayo ``.pgo`` cues
                        -> step-hold tracks through the rig's shape table
``midi_file``           Standard MIDI Files (format 0/1): controllers and notes through the
                        tempo map, in live MIDI's words
======================  ===============================================================

Each reader is one module; what every reader shares is in ``common``. The rig names a
file, the unit map and the channel; a reader never guesses a unit.
"""
