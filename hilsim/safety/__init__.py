"""The only way to the wire: every command passes the safety filter before it is sent.

``filter``  :class:`SafetyFilter`: finite, within limits, speed and acceleration; soft start
``limits``  its parameters, events and counters (data types)
"""

from hilsim.safety.filter import SafetyFilter
from hilsim.safety.limits import (
    COUNTER_KINDS,
    SafetyCounters,
    SafetyEvent,
    SafetyFault,
    SafetyParams,
)

__all__ = [
    "COUNTER_KINDS",
    "SafetyCounters",
    "SafetyEvent",
    "SafetyFault",
    "SafetyFilter",
    "SafetyParams",
]
