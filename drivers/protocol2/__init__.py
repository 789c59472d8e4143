"""Dynamixel Protocol 2.0 facts that both sides of the wire share.

==================  ==============================================================================
``control_table``   addresses, sizes and ranges of the X-series control table; status error bits;
                    model numbers; baud-rate table; the Alert bit
``wire_time``       bytes and seconds of a Sync Write + (Fast) Sync Read cycle; USB latency timer;
                    default turnaround
``ids``             servo ID lists as people write them (``1-4``, ``1,3,5``)
``crc``             the CRC-16 every packet carries
==================  ==============================================================================

The host driver (:mod:`drivers.dynamixel`) and the emulator (:mod:`drivers.dxlsim`) both import
from here; this package imports neither of them, nor ``dynamixel_sdk``.
"""
