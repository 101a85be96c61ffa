"""Run ROBOTIS' Protocol 2.0 example programs against `trajgen virtual-bus`.

The examples are DynamixelSDK's ``python/tests/protocol2_0/*.py`` (not part of
this project: clone https://github.com/ROBOTIS-GIT/DynamixelSDK and pass that
directory). Each is copied to a temporary file with only its port name
changed, and run against a fresh `trajgen virtual-bus` (two for
multi_port.py); key presses are scripted on a pty standing in for the
keyboard: "human" presses 0.5 s after each prompt, "instant" 0.05 s after.
Two rounds of "press any key", then ESC; SPACE 1 s after clear_multi_turn's
prompt. The examples' output is drained all the while, as a terminal does
(an example that prints every poll blocks on a full pipe otherwise, and then
stops its servo at a stale position). An example runs cleanly when it exits 0
within 60 s and prints no error ([TxRxResult], [RxPacketError], "failed", a traceback...).

Run: .venv/bin/python bench/robotis_examples.py DIR [human|instant] [NAME ...] [--lockstep]
"""

import os
import pty
import re
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import time

HERE = sys.argv[1]
TRAJGEN = shutil.which("trajgen", path=os.path.dirname(sys.executable)) or "trajgen"
PYTHON = sys.executable
MODE = sys.argv[2] if len(sys.argv) > 2 else "human"
ONLY = [a for a in sys.argv[3:] if not a.startswith("--")]
BUS_ARGS = [a for a in sys.argv[3:] if a.startswith("--")]
EXAMPLES = [
    "ping",
    "broadcast_ping",
    "read_write",
    "sync_read_write",
    "bulk_read_write",
    "fast_sync_read",
    "fast_bulk_read",
    "indirect_address",
    "reboot",
    "factory_reset",
    "clear_multi_turn",
    "multi_port",
]
PROMPT_RE = re.compile(
    rb"Press any key to continue|Press any key to reboot|Press SPACE key"
    rb"|Press any key to terminate"
)
ERRORS = re.compile(
    r"\[TxRxResult\]|\[RxPacketError\]|Failed|failed|Traceback|no status packet|unavailable|Error"
)


def start_bus(*extra):
    proc = subprocess.Popen(
        [TRAJGEN, "virtual-bus", *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    port = proc.stdout.readline().strip()
    return proc, port


def run(name):
    buses = [start_bus(*BUS_ARGS)]
    if name == "multi_port":
        buses.append(start_bus("--ids", "2,3,4"))
    source = open(os.path.join(HERE, name + ".py")).read()
    source = source.replace("'/dev/ttyUSB0'", repr(buses[0][1]))
    if len(buses) > 1:
        source = source.replace("'/dev/ttyUSB1'", repr(buses[1][1]))
    fd, path = tempfile.mkstemp(prefix=name + "_", suffix=".py")
    with os.fdopen(fd, "w") as f:
        f.write(source)
    master, slave = pty.openpty()
    start = time.monotonic()
    proc = subprocess.Popen(
        [PYTHON, "-u", path], stdin=slave, stdout=subprocess.PIPE, stderr=subprocess.STDOUT
    )
    os.close(slave)
    out = b""
    presses = 0
    scanned = 0  # prompts before this offset of `out` are answered
    limit = 60.0
    delay = 0.5 if MODE == "human" else 0.05
    keys: list[tuple[float, bytes]] = []  # (when, key) presses due
    # The example's output is read all the time, key presses included: a
    # terminal never stops taking output, and an example blocked on a full
    # pipe would act on a stale Present Position.
    while proc.poll() is None and time.monotonic() - start < limit:
        ready, _, _ = select.select([proc.stdout], [], [], 0.005)
        if ready:
            out += os.read(proc.stdout.fileno(), 65536)
        for match in PROMPT_RE.finditer(out, scanned):
            prompt = match.group().decode()
            scanned = match.end()
            when = (keys[-1][0] if keys else time.monotonic()) + delay
            if prompt.startswith("Press SPACE"):
                keys.append((when + 1.0, b" "))
            elif prompt.startswith("Press any key to continue") and presses >= 2:
                keys.append((when, b"\x1b"))
            else:
                keys.append((when, b"n"))
                presses += 1
        scanned = max(scanned, len(out) - 40)  # a prompt may be cut between reads
        while keys and keys[0][0] <= time.monotonic():
            os.write(master, keys.pop(0)[1])
    timed_out = proc.poll() is None
    if timed_out:
        proc.kill()
    proc.wait()
    rest = proc.stdout.read() or b""
    out += rest
    os.close(master)
    for bus, _ in buses:
        bus.send_signal(signal.SIGINT)
        bus.wait(timeout=5)
    os.remove(path)
    text = out.decode(errors="replace")
    errors = ERRORS.findall(text)
    clean = proc.returncode == 0 and not timed_out and not errors
    took = time.monotonic() - start
    return clean, proc.returncode, timed_out, errors, took, text


def main() -> None:
    load = os.getloadavg()[0]
    clean_count = 0
    names = ONLY or EXAMPLES
    for name in names:
        clean, rc, timed_out, errors, took, text = run(name)
        clean_count += clean
        verdict = "clean" if clean else "NOT clean"
        late = "timeout " if timed_out else ""
        print(f"{name:18s} {verdict:10s} exit {rc} {late}{took:5.1f} s  {sorted(set(errors))}")
        if not clean or os.environ.get("SHOW"):
            print("    " + text[-1500:].replace("\n", "\n    "))
    print(f"{clean_count} of {len(names)} ran cleanly ({MODE} key presses)")
    print(f"load average {load:.2f} before, {os.getloadavg()[0]:.2f} after")


if __name__ == "__main__":
    main()
