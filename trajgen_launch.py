"""The ``trajgen`` console script's entry point, outside the ``trajgen`` package.

Importing ``trajgen.cli`` (numpy, then every command module) takes 0.3-2 s; a
Ctrl-C in that time would print a traceback from the middle of an import,
which looks like a broken install. The entry point lives here, where nothing
is imported yet, so that Ctrl-C while the command line loads ends as it does
once it runs: exit status 130 and one line.
"""

import sys

#: The exit status of an interrupted command (``trajgen.cli.common.EXIT_INTERRUPTED``).
_INTERRUPTED = 130


def main() -> int:
    """Load ``trajgen.cli`` and run its ``main``; returns the exit status."""
    try:
        from trajgen.cli import main as run
    except KeyboardInterrupt:
        print("\ntrajgen: interrupted while starting", file=sys.stderr)
        return _INTERRUPTED
    return run()
