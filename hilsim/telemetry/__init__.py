"""A run's telemetry: written during the show, read back and drawn after it.

==========  =====================================================================================
``format``  the run directory: file names, CSV columns, number formats (writer and reader share it)
``ring``    the lock-free single-producer ring of tick rows between the loop and the writer thread
``sinks``   one writer per telemetry format: exact CSV, csv.gz, Parquet (``telemetry.format``)
``writer``  :class:`TelemetryWriter`: the rows (through a sink), ``events.jsonl``, fsync,
            ``summary.json``; the loop's side of it (``writer_thread``: the writer thread's)
``stats``   :class:`RunStats`: the one book of per-tick facts behind the summary
``reader``  :func:`read_run`: a run directory back as arrays
``plots``   the PNGs of a run (matplotlib imported inside the functions)
==========  =====================================================================================

Importing this package imports neither matplotlib nor numpy's plotting helpers.
"""

from hilsim.telemetry.format import TelemetryError
from hilsim.telemetry.reader import NotARunError, Run, RunFormatError, read_run
from hilsim.telemetry.writer import TelemetryWriter, WriterFailedError

__all__ = [
    "NotARunError",
    "Run",
    "RunFormatError",
    "TelemetryError",
    "TelemetryWriter",
    "WriterFailedError",
    "read_run",
]
