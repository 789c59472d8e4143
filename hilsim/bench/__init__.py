"""``hilsim bench``: how fast can this host and this bus go, beside the physical limit.

=============== ==============================================================================
``model``       the wire-time model of one Sync Write + Sync Read cycle (plain or Fast)
``sched``       the tick scheduler alone: lateness statistics, SCHED_FIFO, CPU %
``cyclictest``  running and parsing rt-tests' cyclictest beside our scheduler
``session``     opening a port (hardware or ``dxlsim://``) through our PortHandler + the SDK
``busrate``     back-to-back cycles through the SDK's group objects vs the model
``latency``     command to wire, command to motion, feedback age
``diagnose``    latency timer, Return Delay Time, baud rate, firmware: fixes and their rates
``runner``      what to measure (``BenchPlan``) and running it into a ``BenchReport``
``report``      the JSON and the terminal summary
``plots``       the PNGs (matplotlib imported inside the functions)
=============== ==============================================================================

Nothing here is imported by ``import hilsim``; the CLI imports it inside ``run``.
"""
