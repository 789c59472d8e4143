"""Hardware side of hilsim: the Dynamixel driver and the emulated Dynamixel bus.

Nothing here imports :mod:`hilsim`; only :mod:`drivers.dynamixel` imports ``dynamixel_sdk``.
"""
