"""What loading numba costs, and where it pays: whole-process ``trajgen plan`` times.

1. Start-up: ``import numba`` plus loading the cached kernel, in a fresh process.
2. Per-sample time of a large evaluation with the numpy path and with the kernel
   (one process, same spline): the break-even sample count = start-up / saving.
3. ``trajgen plan`` on the built-in example (8 s) at 100 Hz, 1 kHz and 100 kHz,
   whole process (``python -m trajgen plan --out plan.csv``), with numba off
   (``TRAJGEN_NUMBA=0``), on the default policy (``auto``: loaded only from
   ``trajgen.fast.LOAD_SAMPLES`` samples) and forced on (``1``); median of 5 (3 at 100 kHz),
   interleaved. Target (issue 10): no command slower with numba installed.

    python bench/numba_load.py
"""

import os
import subprocess
import sys
import tempfile
import time

import numpy as np

CODE_LOAD = (
    "import time; t0 = time.perf_counter()\n"
    "import numpy as np\n"
    "from trajgen import BlendingSpline, fast\n"
    "fast.MODE = 'always'\n"
    "BlendingSpline([[1, 0, 0, 0], [0, 0, 0, 1]], [0.0, 1.0]).evaluate(np.zeros(1))\n"
    "print(time.perf_counter() - t0)\n"
)
CODE_IMPORT = (
    "import time; t0 = time.perf_counter()\n"
    "import numpy as np\n"
    "from trajgen import BlendingSpline\n"
    "BlendingSpline([[1, 0, 0, 0], [0, 0, 0, 1]], [0.0, 1.0]).evaluate(np.zeros(1))\n"
    "print(time.perf_counter() - t0)\n"
)
CODE_PER_SAMPLE = (
    "import time, numpy as np\n"
    "from trajgen import fast, load_keyframe_file\n"
    "from trajgen.keyframes import BUILTIN_EXAMPLE\n"
    "s = load_keyframe_file(BUILTIN_EXAMPLE).spline()\n"
    "t = np.linspace(s.t_start, s.t_end, 800_001)\n"
    "out = []\n"
    "for mode in ('never', 'always'):\n"
    "    fast.MODE = mode\n"
    "    s.evaluate(t[:1000])\n"
    "    best = 1e9\n"
    "    for _ in range(3):\n"
    "        t0 = time.perf_counter(); s.evaluate(t); best = min(best, time.perf_counter() - t0)\n"
    "    out.append(best / len(t))\n"
    "print(*out)\n"
)


def run(code, env=None):
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
    )
    return proc.stdout.split()


def plan_time(rate, numba, out):
    env = dict(os.environ, TRAJGEN_NUMBA=numba)
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "trajgen", "plan", "--rate", str(rate), "--out", out],
        env=env,
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    return time.perf_counter() - t0


def main():
    from trajgen import fast

    print(f"load average {os.getloadavg()[0]:.2f} (2 cores); LOAD_SAMPLES = {fast.LOAD_SAMPLES:,}")
    base = np.median([float(run(CODE_IMPORT)[0]) for _ in range(3)])
    load = np.median([float(run(CODE_LOAD)[0]) for _ in range(3)])
    numpy_s, numba_s = (float(x) for x in run(CODE_PER_SAMPLE))
    extra = load - base
    print(f"start-up without numba {base * 1e3:.0f} ms, with the kernel loaded {load * 1e3:.0f} ms")
    print(
        f"per sample (q, omega, alpha, jerk at 800,001 samples): numpy {numpy_s * 1e9:.0f} ns, "
        f"kernel {numba_s * 1e9:.0f} ns; break-even {extra / (numpy_s - numba_s):,.0f} samples"
    )
    print()
    print("| trajgen plan | samples | TRAJGEN_NUMBA=0 (s) | auto (s) | =1 (s) | auto / off |")
    print("|---|---|---|---|---|---|")
    out = os.path.join(tempfile.mkdtemp(), "plan.csv")
    for rate in (100, 1000, 100_000):
        times = {m: [] for m in ("0", "auto", "1")}
        for _ in range(5 if rate < 100_000 else 3):
            for m in times:
                times[m].append(plan_time(rate, m, out))
        med = {m: float(np.median(v)) for m, v in times.items()}
        print(
            f"| --rate {rate} | {8 * rate + 1:,} | {med['0']:.2f} | {med['auto']:.2f} "
            f"| {med['1']:.2f} | {med['auto'] / med['0']:.2f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
