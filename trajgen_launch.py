"""The ``trajgen`` console script's entry point, outside the ``trajgen`` package.

Importing ``trajgen.cli`` (numpy, then every command module) takes 0.3-2 s; a
Ctrl-C in that time would print a traceback from the middle of an import,
which looks like a broken install. So the first statements of this module make
SIGINT, SIGTERM and SIGHUP end the start-up at once with one line and exit
status 128 + the signal number (130, 143, 129): nothing has been read or
written yet, so there is nothing to stop safely. They use ``_signal``, the
interpreter's built-in module that is loaded before any Python code runs, so
nothing is imported before the handlers are in place (``signal`` would import
``enum`` first). Once ``trajgen.cli`` is loaded the previous handlers come back
and the command's own handling takes over (``trajgen.cli.main``).

What this cannot cover is the interpreter's own start-up before this module's
first line (``site`` and the ``.pth`` files of the environment): docs/cli.md
gives its measured length, against a two-line script's.
"""

import _signal

#: What an interrupted start-up says (one line, after the terminal's ``^C``).
_MESSAGE = "\ntrajgen: interrupted while starting\n"
#: The signals that end the start-up (the command line's stop signals).
_STOP_SIGNALS = (_signal.SIGINT, _signal.SIGTERM, _signal.SIGHUP)


def _stop_starting(signum, frame):
    """A stop signal while the command line loads: one line, then exit at once.

    ``os._exit`` rather than an exception: raised inside an import, an exception
    can be turned into an ImportError by the module being loaded."""
    import os  # loaded by then: ``site`` imports it before any script

    os.write(2, _MESSAGE.encode())
    os._exit(128 + signum)


_PREVIOUS = {s: _signal.signal(s, _stop_starting) for s in _STOP_SIGNALS}

import sys  # noqa: E402  (after the handlers: nothing before them)

#: The exit status of an interrupted command (``trajgen.cli.common.EXIT_INTERRUPTED``).
_INTERRUPTED = 128 + _signal.SIGINT


def _hand_over() -> None:
    """Give the stop signals back to the handlers before this module's."""
    for s, handler in _PREVIOUS.items():
        _signal.signal(s, handler)


def main() -> int:
    """Load ``trajgen.cli`` and run its ``main``; returns the exit status."""
    try:
        from trajgen.cli import main as run

        _hand_over()  # the command's own handling from here
        return run()
    except KeyboardInterrupt:  # raised by the import itself, or just after the hand-over
        print(_MESSAGE, end="", file=sys.stderr)
        return _INTERRUPTED
    finally:
        _hand_over()
