"""The Dynamixel driver: dynamixel-sdk behind snake_case, on any pyserial port and injected clock.

This package is the only place that imports ``dynamixel_sdk``.
"""
