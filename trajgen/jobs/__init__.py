"""Whole runs of the ``trajgen`` commands as library calls: where the core, the
drivers and the simulator meet (the command line is the other such place, and
only parses and prints around these).

``checked_file``: a keyframe file with every table checked (``load_checked``).
``stream_job``: ``trajgen stream`` (and what ``follow`` and ``excite`` stream):
:class:`StreamJob` plans a file for a bus or the virtual gimbal, runs it through
a ``trajgen.drivers.session.Session`` and gives a :class:`StreamResult` (exit
status, servo states, the torque report of a virtual run, the JSON report)::

    from trajgen.jobs import run_stream_file

    result = run_stream_file("shot.toml", virtual=True)
    print(result.format())

Importing this package loads neither MuJoCo nor the servo SDK: they load when a
job is planned or run.
"""

from trajgen.jobs.checked_file import CheckedFile, check_timing, load_checked
from trajgen.jobs.stream_job import (
    IdCount,
    LimitsRefused,
    NoPort,
    StreamJob,
    StreamResult,
    run_stream_file,
)

__all__ = [
    "CheckedFile",
    "IdCount",
    "LimitsRefused",
    "NoPort",
    "StreamJob",
    "StreamResult",
    "check_timing",
    "load_checked",
    "run_stream_file",
]
