"""Loading a large keyframe file: trajgen's reader against tomllib alone.

python bench/keyframe_load.py [N]

Writes N keyframes (default 950,000, about 50 MB: the issue's file) to a
temporary file and times, in the same run, each in a fresh process:
``tomllib.loads`` of the text (the peer: what ``load_keyframe_file`` did
before, and then it also looped over every keyframe in Python) and
``load_keyframe_file`` (the fast reader plus every check). Peak memory is the
process's maximum resident set size, less that of a process that only imports
the same modules.
"""

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

READERS = {
    "load_keyframe_file (fast reader + checks)": (
        "from trajgen.keyframes import load_keyframe_file as f; p = sys.argv[1]"
    ),
    "tomllib.loads alone (the peer)": (
        "import tomllib; from trajgen.keyframes import load_keyframe_file\n"
        "f = lambda p: tomllib.loads(open(p).read()); p = sys.argv[1]"
    ),
}
RUN = """
import resource, sys, time
{setup}
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
start = time.perf_counter()
if sys.argv[2] == "run":
    f(p)
print(time.perf_counter() - start, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base)
"""


def write_file(path: Path, n: int) -> None:
    rng = np.random.default_rng(3)
    pan, tilt, roll = rng.uniform(-60, 60, (3, n)).round(2)
    with path.open("w") as f:
        f.write('[spline]\nk = 2\n\n[gimbal]\nservo = "XM430-W350"\n\n')
        for i in range(n):
            f.write(f"[[keyframes]]\nt = {0.5 * i}\npan = {pan[i]:g}\ntilt = {tilt[i] / 2:g}\n")
            f.write(f"roll = {roll[i] / 6:.2f}\n\n")


def run(setup: str, path: Path) -> tuple[float, float]:
    code = RUN.format(setup=setup)
    out = subprocess.run(
        [sys.executable, "-c", code, str(path), "run"], capture_output=True, text=True, check=True
    )
    if out.returncode:
        raise RuntimeError(out.stderr.strip().splitlines()[-1])
    seconds, kib = out.stdout.split()
    return float(seconds), int(kib) / 1024


def main():
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 950_000
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "big.toml"
        write_file(path, n)
        size_mb = path.stat().st_size / 1e6
        load_before = os.getloadavg()
        figures = {name: run(setup, path) for name, setup in READERS.items()}
        load_after = os.getloadavg()
    print(f"file: {n:,} keyframes, {size_mb:.1f} MB")
    print(f"machine load (1 min) before / after: {load_before[0]:.2f} / {load_after[0]:.2f}")
    print("| reader | time (s) | peak memory added (MB) |")
    print("|---|---|---|")
    for name, (seconds, mb) in figures.items():
        print(f"| {name} | {seconds:.1f} | {mb:.0f} |")
    (ours_s, ours_mb), (peer_s, peer_mb) = figures.values()
    print(f"ratio tomllib / ours: {peer_s / ours_s:.1f}x time, {peer_mb / ours_mb:.1f}x memory")


if __name__ == "__main__":
    main()
