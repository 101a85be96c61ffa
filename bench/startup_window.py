"""How long Ctrl-C at start-up can still give Python's own traceback, before our code runs.

``trajgen_launch`` (the ``trajgen`` script's entry point) makes SIGINT, SIGTERM
and SIGHUP end the start-up with one line as its first statements. Before
those, the interpreter itself runs: from ``exec`` until Python installs its
SIGINT handler a Ctrl-C kills the process silently (the shell shows 130, no
output); from then until our first statement it raises KeyboardInterrupt inside
``site`` (the environment's ``.pth`` files) or the script and prints a
traceback. This is that window, measured on the real script by watching
``/proc/<pid>/status`` (SigCgt, polled every 0.2 ms: SIGINT caught = Python's
handler; SIGTERM caught = ours; SIGTERM no longer caught = handed over to
``trajgen.cli``). A traceback "in our code" is one with a frame in trajgen's
own files.

Peers, in the same run and the same interpreter:

- ``peer``: a three-line script file that installs a SIGTERM handler as its
  first statement (with ``_signal``, as ours does) and then works for 0.3 s
  (as ``trajgen`` goes on loading: a sleeping peer would leave the poller more
  of the shared cores and be seen sooner): the window every Python program in
  this environment has, ``site`` and its ``.pth`` files included;
- ``peer -S``: the same without ``site``: the interpreter's own floor, so that
  ``peer - peer -S`` is what this environment's ``site`` costs every program
  (an editable install's import hook is there).

Then ``--probe`` sends SIGINT at random times in the first 300 ms and counts
the outcomes (seeded). ``--venv`` measures another environment's ``trajgen``
(say a scratch venv with ``pip install .``, what a registry user has).

    python bench/startup_window.py [--runs 20] [--probe 40] [--venv PATH]
"""

import argparse
import collections
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

#: The peer script (see above).
PEER = (
    "import _signal; _signal.signal(15, lambda *a: None)\n"
    "import time; end = time.perf_counter() + 0.3\n"
    "while time.perf_counter() < end: pass"
)
INT, TERM = 1 << (signal.SIGINT - 1), 1 << (signal.SIGTERM - 1)


def caught(pid: int) -> int | None:
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    return int(re.search(r"^SigCgt:\s*([0-9a-f]+)", text, re.M).group(1), 16)


def times(argv) -> tuple[float, float, float]:
    """Seconds from Popen to Python's SIGINT handler, to our SIGTERM handler, to the
    hand-over (SIGTERM no longer caught; nan for the peer)."""
    start = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    seen = {}
    while proc.poll() is None:
        mask = caught(proc.pid)
        if mask is None:
            break
        now = time.perf_counter() - start
        if mask & INT:
            seen.setdefault("python", now)
        if mask & TERM:
            seen.setdefault("ours", now)
        elif "ours" in seen:
            seen.setdefault("handed", now)
            break
        time.sleep(0.0002)  # leave the (shared) cores to the process measured
    proc.kill()
    proc.wait()
    return seen.get("python", np.nan), seen.get("ours", np.nan), seen.get("handed", np.nan)


def probe(trajgen: Path, n: int, seed: int) -> collections.Counter:
    """Outcomes of SIGINT at random times in the first 300 ms of ``trajgen plan``."""
    rng = np.random.default_rng(seed)
    counts = collections.Counter()
    for delay in rng.uniform(0.0, 0.3, n):
        argv = [str(trajgen), "plan", "--out", os.devnull, "--rate", "5000"]
        proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        err = proc.communicate()[1].decode()
        if "Traceback" in err:
            ours = re.search(r'File "[^"]*(trajgen_launch\.py|/trajgen/|/drivers/|/sim/)', err)
            where = "in our code" if ours else "before our first statement (site, the script)"
            counts[f"traceback {where}"] += 1
        elif proc.returncode == -signal.SIGINT and not err:
            counts["killed before Python's handler (no output)"] += 1
        elif proc.returncode == 130 and len(err.strip().splitlines()) == 1:
            counts["exit 130, one line"] += 1
        else:
            lines = err.strip().splitlines()
            counts[
                f"exit {proc.returncode}, {len(lines)} lines: {lines[-1][:70] if lines else ''!r}"
            ] += 1
    return counts


def median_difference_ms(a, b, seed: int = 0) -> tuple[float, float, float]:
    """Median of ``a`` minus median of ``b`` (ms) and its bootstrapped 90 % interval."""
    rng = np.random.default_rng(seed)
    a, b = a[np.isfinite(a)], b[np.isfinite(b)]
    boot = [
        np.median(rng.choice(a, a.size)) - np.median(rng.choice(b, b.size)) for _ in range(2000)
    ]
    low, high = np.percentile(boot, [5, 95])
    return 1000 * (np.median(a) - np.median(b)), 1000 * low, 1000 * high


def _ms(values) -> str:
    ms = 1000 * values[np.isfinite(values)]
    return f"median {np.median(ms):6.1f} ms, p90 {np.percentile(ms, 90):6.1f} ms"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--probe", type=int, default=40)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--venv", type=Path, default=Path(sys.prefix), help="the environment (default: this one)"
    )
    args = parser.parse_args()
    python, trajgen = args.venv / "bin" / "python", args.venv / "bin" / "trajgen"
    pth = sorted(p.name for p in args.venv.glob("lib/python*/site-packages/*.pth"))
    print(f"environment: {args.venv} (.pth files: {', '.join(pth) or 'none'})")
    print(f"load before: {os.getloadavg()}")
    script = Path(tempfile.mkdtemp()) / "peer.py"
    script.write_text(PEER + "\n")
    ours, peer, floor = [], [], []
    for _ in range(args.runs):  # interleaved: the same load for all three
        ours.append(times([str(trajgen), "plan", "--out", os.devnull]))
        peer.append(times([str(python), str(script)]))
        floor.append(times([str(python), "-S", str(script)]))
    ours, peer, floor = np.array(ours), np.array(peer), np.array(floor)
    window, peer_window, floor_window = (a[:, 1] - a[:, 0] for a in (ours, peer, floor))
    for name, values in [
        ("exec -> Python's SIGINT handler (silent kill)", ours[:, 0]),
        ("Python's handler -> our first statement (traceback window)", window),
        ("  peer: the same for a three-line script", peer_window),
        ("  peer -S: the same without site (the interpreter's floor)", floor_window),
        ("our first statement -> hand-over to trajgen.cli (one line)", ours[:, 2] - ours[:, 1]),
    ]:
        print(f"{name}: {_ms(values)}")
    ratio = np.nanmedian(window) / np.nanmedian(peer_window)
    print(f"traceback window, ours / peer (medians): {ratio:.2f}")
    for name, (a, b) in [
        ("ours - peer (the script, trajgen_launch found and loaded)", (window, peer_window)),
        ("peer - peer -S (this environment's site: every program)", (peer_window, floor_window)),
    ]:
        d, low, high = median_difference_ms(a, b, args.seed)
        print(f"  {name}: {d:+.1f} ms (90 % bootstrap interval {low:+.1f} .. {high:+.1f} ms)")
    if args.probe:
        print(f"SIGINT at uniform random times in 0-300 ms, {args.probe} runs (seed {args.seed}):")
        for outcome, count in probe(trajgen, args.probe, args.seed).most_common():
            print(f"  {count:3d}  {outcome}")
    print(f"load after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
