"""Readers of other tools' animation files (issue 13), each to tracks in joint radians.

==================  ===================================================================
``common``          :class:`FormatError`, :class:`UnitMap`, :class:`SampledTrack`
==================  ===================================================================

Each reader is one module; what every reader shares is in ``common``. The rig names a
file, the unit map and the channel; a reader never guesses a unit.
"""
