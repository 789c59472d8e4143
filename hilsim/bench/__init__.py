"""``hilsim bench``: how fast can this host and this bus go, beside the physical limit.

=============== ==============================================================================
``sched``       the tick scheduler alone: lateness statistics, SCHED_FIFO, CPU %
``cyclictest``  running and parsing rt-tests' cyclictest beside our scheduler
``ports``       the ports it opens: ``dxlsim://`` URLs on the clock it chooses
``busrate``     back-to-back cycles through the SDK's group objects vs the wire-time model
                (:mod:`drivers.protocol2.wire_time`)
``latency``     command to wire, command to motion, feedback age
``tick``        the host's cost of one tick: hilsim's whole tick beside a bare SDK cycle
``cpu``         host CPU per bus cycle over a pty: the SDK's busy-poll beside hilsim's port
``diagnose``    latency timer, Return Delay Time, baud rate, firmware: fixes and their rates
``runner``      what to measure (``BenchPlan``) and running it into a ``BenchReport``
``report``      the JSON and the terminal summary
``plots``       the PNGs (matplotlib imported inside the functions)
=============== ==============================================================================

Nothing here is imported by ``import hilsim``; the CLI imports it inside ``run``.
"""
