"""Stream a keyframe file as ``trajgen stream FILE --virtual --json OUT.json`` does, from Python.

``trajgen.jobs.StreamJob`` is the whole command without its parsing and printing:
``from_file`` checks every table of the file and plans the joint stream with its
led goals (no hardware yet); ``run`` opens the port, or here a virtual servo bus
around the MuJoCo gimbal of the file's ``[gimbal]`` tables, brings the servos up,
streams, stops them safely, and judges the torque of what was streamed. The
``StreamResult`` holds the exit status the command would give, each servo's
state, the torque report, and the JSON report ``--json`` writes. For real
servos: ``port="/dev/ttyUSB0"`` (or the file's ``[bus] port``) instead of
``virtual=True``.

Run: .venv/bin/python examples/06_stream_file.py [--file examples/raster.toml] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from trajgen import BUILTIN_EXAMPLE
from trajgen.jobs import StreamJob


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--file", type=Path, default=BUILTIN_EXAMPLE, help="default: built-in")
    parser.add_argument("--json", type=Path, help="write the report here")
    options = parser.parse_args()

    job = StreamJob.from_file(options.file, virtual=True, on_stop="hold")
    print(f"planned {len(job.trajectory.t)} frames at {job.rate_hz:g} Hz, lead {job.lead!r}")
    result = job.run()
    print(result.format())
    report = result.to_json_dict()
    if options.json:
        options.json.write_text(json.dumps(report, indent=2))
    print(f"status {result.exit_status}; servos {report['servos']}")
    return result.exit_status


if __name__ == "__main__":
    raise SystemExit(main())
