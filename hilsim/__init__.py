"""hilsim: animatronic joints as damped springs, integrated in real time and streamed to servos.

Importing ``hilsim`` never imports matplotlib or dynamixel_sdk.
"""

__version__ = "0.1.0"
