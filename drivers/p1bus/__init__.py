"""The host side of the Protocol 1.0-framed servo families: Feetech STS/SCS and Dynamixel
AX/MX (Protocol 1.0 firmware), on the same port layer as :mod:`drivers.dynamixel`.

``table`` the families as the host uses them (models, registers, read method, error bits);
``link`` transactions; ``bus`` :class:`~drivers.p1bus.bus.P1ServoBus`, the loop's backend;
``startup`` the start-up check; ``health`` torque, health, EEPROM writes, the exit policy;
``scan`` finding servos by per-ID ping. The packets and encodings are
:mod:`drivers.protocol1`'s, shared with the emulator. ``table`` loads no SDK, so a rig can
name its models without it.
"""
