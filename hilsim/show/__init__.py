"""A rig on a bus, from the start-up check to the exit policy.

``session``      a rig into running parts; open and check the bus; run it (run_show)
``loop``         HilLoop: the start, the tick, every way out (the exit policy)
``warm_up``      tick 0 as warm as later ones (real time)
``servo_watch``  when a servo has failed; a tripped Bus Watchdog recovered
``monitors``     the rules' bookkeeping: host stalls, silence budget, following error
``events``       rate-limited lines of events.jsonl
``realtime``     SCHED_FIFO, CPU affinity, timer slack for the loop thread
``group``        several buses of one figure: one process each, one start, one stop
``preview``      the targets through the springs and safety filter, no bus (hilsim tracks)
"""

from hilsim.show.api import Show, ShowError, ShowRefusedError, ShowResult
from hilsim.show.stop import StopFlag

__all__ = ["Show", "ShowError", "ShowRefusedError", "ShowResult", "StopFlag"]
