"""Output files: checked before any work (writable, not an input, not a kernel
interface, the right suffix, the optional package installed) and written
atomically (a temporary file beside the target, renamed when whole)."""

from __future__ import annotations

import errno
import importlib.util
import os
import stat
import tempfile
from contextlib import contextmanager
from pathlib import Path

from trajgen.cli.messages import BadInput

#: Image formats ``--plot`` accepts (matplotlib's Agg backend writes each).
PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")
#: Telemetry formats (``trajgen stream --telemetry``, ``excite``, read by ``identify``).
TELEMETRY_SUFFIXES = (".csv", ".npz", ".mcap")

#: Folders of kernel interfaces, never an output (``--out /proc/...``).
_KERNEL_FOLDERS = ("/proc", "/sys")


def check_output_path(
    option: str, path: str | None, suffixes: tuple[str, ...] = (), inputs=()
) -> None:
    """Refuse an output path that cannot be written, before any work is done.

    Parameters
    ----------
    option : str
        The option, named in the message (``"--json"``).
    path : str or None
        What the user gave; None (option not given) passes.
    suffixes : tuple of str
        Accepted extensions (lower case, with the dot); empty accepts any.
    inputs : iterable of str or Path
        Files the command reads: an output that is one of them (by name, through
        a symbolic link or as a hard link) is refused, as writing it would
        destroy the input.

    Raises
    ------
    BadInput
        The name is empty or ``-``, the folder is missing or not writable, the path is a
        directory, a loop of symbolic links, a kernel interface (``/proc``, ``/sys``), an
        input, an existing file that cannot be written, or the extension is not one of
        ``suffixes``.
    """
    if path is None:
        return
    p = Path(path)
    if not path:
        raise BadInput(f"{option} '': an empty name; give a file name")
    if path == "-":
        raise BadInput(f"{option} '-': standard output is not written here; give a file name")
    if p.is_dir():
        raise BadInput(f"{option} {path!r}: is a directory; give a file name")
    if _link_loop(p):
        raise BadInput(f"{option} {path!r}: is a loop of symbolic links; give a file name")
    # /dev/stdout leads into /proc/self/fd: devices are written in place, not refused.
    names = {os.path.abspath(p)} if _in_place(p) else {os.path.abspath(p), os.path.realpath(p)}
    for kernel in _KERNEL_FOLDERS:
        if any(name == kernel or name.startswith(kernel + os.sep) for name in names):
            raise BadInput(
                f"{option} {path!r}: is in {kernel}, a kernel interface, not a place for "
                "files; give a file name"
            )
    for source in inputs:
        if _same_file(p, Path(source)):
            raise BadInput(
                f"{option} {path!r}: is the input file {str(source)!r}; writing it would "
                "destroy it: give another name"
            )
    if _in_place(p):
        if p.exists() and not os.access(p, os.W_OK):
            raise BadInput(f"{option} {path!r}: is not writable")
        return  # a device or pipe (/dev/null, /dev/stdout): written as it is
    if suffixes and p.suffix.lower() not in suffixes:
        raise BadInput(f"{option} {path!r}: expected a {' or '.join(suffixes)} file")
    folder = p.parent
    if not folder.is_dir():
        raise BadInput(f"{option} {path!r}: no such folder {str(folder)!r}")
    if p.exists() and not os.access(p, os.W_OK):
        raise BadInput(f"{option} {path!r}: file is not writable")
    if not os.access(folder, os.W_OK | os.X_OK):
        # Every output is written to a temporary file in its folder, then renamed.
        raise BadInput(f"{option} {path!r}: folder {str(folder)!r} is not writable")


def check_model_beside(option: str, out, source, tables: dict) -> None:
    """Refuse an output keyframe file in another folder than ``source`` when the source's
    ``[gimbal] model`` is a relative name (the written file keeps the name, which would
    no longer lead to the model).

    Raises
    ------
    BadInput
        ``"--out X: the file's [gimbal] model = 'm.xml' is relative to its folder; write
        the fitted file there"``.
    """
    gimbal = tables.get("gimbal", {})
    model = gimbal.get("model") if isinstance(gimbal, dict) else None
    if (
        isinstance(model, str)
        and not Path(model).is_absolute()
        and Path(out).resolve().parent != Path(source).resolve().parent
    ):
        raise BadInput(
            f"{option} {out}: the file's [gimbal] model = {model!r} is relative to its "
            "folder; write the fitted file there"
        )


def _link_loop(path: Path) -> bool:
    """Whether ``path`` is a symbolic link that never ends in a file or a missing name."""
    try:
        os.stat(path)
    except OSError as e:
        return e.errno == errno.ELOOP
    return False


def _same_file(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` name one file (same path, a link to it, a hard link)."""
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet)
        return os.path.realpath(a) == os.path.realpath(b)


def _in_place(path: Path) -> bool:
    """A device, pipe or socket, or anything in /dev (``/dev/stdout`` redirected to a
    file too): written in place, never replaced by a renamed file."""
    if os.path.abspath(path).startswith("/dev/"):
        return True
    try:
        return not stat.S_ISREG(os.stat(path).st_mode)
    except OSError:
        return False


@contextmanager
def output_path(option: str, path: str):
    """A temporary path beside ``path`` (same suffix) to write an output to; renamed to
    ``path`` when the block ends without error, removed when it fails, so that
    ``path`` is the whole output or untouched. A device (``/dev/null``) is written
    directly; through a symbolic link, the file it names is replaced (the link stays).

    Raises
    ------
    BadInput
        When writing or renaming fails (a full disk, ``/dev/full``): one line
        naming the option and the path; the temporary file is removed.
    """
    target = Path(path)
    if _in_place(target):
        try:
            yield str(target)
        except OSError as e:
            raise BadInput(f"{option} {path!r}: cannot write: {e.strerror or e}") from None
        return
    target = Path(os.path.realpath(target))  # through a symbolic link: replace what it names
    try:
        fd, tmp = tempfile.mkstemp(
            dir=target.parent, prefix=f".{target.name}.", suffix=f".part{target.suffix}"
        )
        os.close(fd)
    except OSError as e:
        raise BadInput(f"{option} {path!r}: cannot write: {e.strerror or e}") from None
    try:
        yield tmp
        if target.exists():  # keep the permissions of the file being replaced
            os.chmod(tmp, stat.S_IMODE(os.stat(target).st_mode))
        else:
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, target)
    except OSError as e:
        raise BadInput(f"{option} {path!r}: cannot write: {e.strerror or e}") from None
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


@contextmanager
def output_file(option: str, path: str, mode: str = "w", **open_kwargs):
    """An open file that becomes ``path`` only when the block ends without error
    (:func:`output_path`); text files are UTF-8 unless told."""
    if "b" not in mode:
        open_kwargs.setdefault("encoding", "utf-8")
    with output_path(option, path) as tmp:
        try:
            with open(tmp, mode, **open_kwargs) as f:
                yield f
        except OSError as e:
            raise BadInput(f"{option} {path!r}: cannot write: {e.strerror or e}") from None


def write_json(option: str, path: str, data) -> None:
    """Write ``data`` as indented JSON to ``path``, whole or not at all."""
    import json

    with output_file(option, path) as f:
        json.dump(data, f, indent=2)


def check_module(option: str, module: str, package: str) -> None:
    """Refuse ``option`` up front when the optional ``module`` is not installed."""
    if importlib.util.find_spec(module) is None:
        raise BadInput(f"{option} needs the {package} package: pip install {package}")


def check_plot_path(path: str | None, inputs=()) -> None:
    """Refuse ``--plot PATH`` up front: a writable image path, and matplotlib installed."""
    check_output_path("--plot", path, PLOT_SUFFIXES, inputs)
    if path is not None:
        check_module("--plot", "matplotlib", "matplotlib")


def check_telemetry_path(path: str | None, suffixes: tuple[str, ...], inputs=()) -> None:
    """Refuse ``--telemetry PATH`` up front: writable, a known suffix, not one of
    ``inputs``, and for ``.mcap`` the ``mcap`` extra installed."""
    check_output_path("--telemetry", path, suffixes, inputs)
    suffix = Path(path or "").suffix
    if suffix not in suffixes and suffix.lower() in suffixes:
        # The writers and `trajgen identify` tell the formats apart by the suffix as written.
        raise BadInput(f"--telemetry {path!r}: write the suffix in lower case ({suffix.lower()})")
    if path and path.lower().endswith(".mcap"):
        check_module("--telemetry", "mcap_ros2", "'trajgen[mcap]'")


def check_stream_outputs(args) -> None:
    """Refuse unusable --telemetry, --json and --plot paths before any work (an output
    that is the keyframe file among them)."""
    inputs = [args.file]
    check_telemetry_path(args.telemetry, TELEMETRY_SUFFIXES, inputs)
    check_output_path("--json", args.json, (".json",), inputs)
    check_plot_path(args.plot, inputs)
