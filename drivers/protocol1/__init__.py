"""Facts both ends of a Protocol 1.0-framed bus share: Dynamixel AX/MX (P1) and Feetech STS/SCS.

==================  ==============================================================================
``packet``          framing ``FF FF ID LEN INST PARAMS CHK``, the checksum, instruction codes,
                    encode/decode, a stream parser, the Sync Write / Sync Read / Bulk Read params
``encoding``        words on the wire: little or big endian, sign-magnitude with a sign bit
``control_table``   families (error bits, Status Return Level, baud codes) and each model's
                    control table (address, size, access, range, default, sign bit), model numbers
``wire_time``       bytes and seconds of a cycle per read method (Sync Read, Bulk Read, READs)
==================  ==============================================================================

Sources: ``docs/dxlsim.md`` and each table's ``source`` field. The host driver and the emulator
(:mod:`drivers.dxlsim`) both import from here; this package imports neither of them, nor
``drivers.dynamixel``, nor any SDK.

API stability: other code is written against these names. Add names; do not rename or remove
them, and do not change what an existing function returns.
"""
