"""MCAP run logs and plans, read back with the ``mcap`` reader and the ROS 2 decoder (no ROS)."""

import csv
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mcap_ros2", reason="needs the mcap extra: pip install 'trajgen[mcap]'")

from mcap.reader import make_reader  # noqa: E402
from mcap_ros2.decoder import DecoderFactory  # noqa: E402

from trajgen.cli import main  # noqa: E402
from trajgen.drivers import streamer  # noqa: E402
from trajgen.drivers.telemetry import TelemetryWriter, telemetry_columns  # noqa: E402
from trajgen.keyframes import load_keyframe_file  # noqa: E402
from trajgen.ros2_messages import McapContents  # noqa: E402
from trajgen.stream import JOINT_NAMES, plan_joint_trajectory  # noqa: E402
from trajgen.telemetry_mcap import FRAME, GOAL, PLAN, PRESENT, read_columns  # noqa: E402

JOINTS = list(JOINT_NAMES)
#: XM430-W350 (the default servo): stall torque / stall current at 12 V.
KT_XM430 = 4.1 / 2.3


def _keyframes(path, seconds=0.8, rate=100):
    lines = ["[stream]", f"rate_hz = {rate}", ""]
    for k, t in enumerate(np.arange(0.0, seconds + 1e-9, 0.4)):
        lines += ["[[keyframes]]", f"t = {t:g}", f"pan = {10 * (k % 2)}", f"tilt = {5 * (k % 2)}"]
    path.write_text("\n".join(lines) + "\n")
    return path


def _decoded(path):
    """Every message of ``path`` through the mcap reader (seeking) and the ROS 2 decoder."""
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [
            (channel.topic, message, ros)
            for _, channel, message, ros in reader.iter_decoded_messages(log_time_order=False)
        ]


def _csv_columns(path):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return {k: [r[k] for r in rows] for k in rows[0]}


class _Both:
    """A telemetry writer that writes one run's rows to MCAP and to CSV."""

    def __init__(self, path, joint_names, models=None):
        self.writers = [
            TelemetryWriter(path, joint_names, models),
            TelemetryWriter(Path(path).with_suffix(".csv"), joint_names, models),
        ]
        self.columns = self.writers[0].columns

    def write(self, row):
        for w in self.writers:
            w.write(row)

    def close(self):
        for w in self.writers:
            w.close()


@pytest.fixture(scope="module")
def excited(tmp_path_factory):
    """One ``trajgen excite --virtual`` run logged to MCAP and CSV at once."""
    folder = tmp_path_factory.mktemp("excite")
    log = folder / "run.mcap"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(streamer, "TelemetryWriter", _Both)
        argv = ["excite", str(_keyframes(folder / "k.toml")), "--virtual", "--seconds", "3"]
        status = main(argv + ["--telemetry", str(log), "--json", str(folder / "r.json")])
    assert status == 0
    return log, log.with_suffix(".csv"), json.loads((folder / "r.json").read_text())


def test_every_frame_is_on_every_topic_once(excited):
    log, csv_path, _ = excited
    frames = len(_csv_columns(csv_path)["frame"])
    messages = _decoded(log)
    for topic in (GOAL, PRESENT, PLAN, FRAME):
        sequences = [m.sequence for t, m, _ in messages if t == topic]
        assert sorted(sequences) == list(range(frames)), topic
    names = {tuple(ros.name) for t, _, ros in messages if t in (GOAL, PRESENT, PLAN)}
    assert names == {tuple(JOINTS)}


def test_run_log_values_equal_the_csv_of_the_same_run(excited):
    log, csv_path, _ = excited
    want = _csv_columns(csv_path)
    contents = McapContents()
    got = read_columns(log, contents)
    assert contents.complete
    assert list(got) == list(want) == telemetry_columns(JOINTS)
    for name, column in want.items():
        if name == "phase":
            assert got[name].tolist() == column
            continue
        numbers = np.array([float(v) if v else math.nan for v in column])
        np.testing.assert_allclose(got[name], numbers, rtol=0, atol=1e-9, err_msg=name)
    # The messages themselves: stamps are the stream clock, effort is current x kt (N m).
    clock = np.array([float(v) for v in want["clock_s"]])
    current = np.array([[float(v) for v in want[f"current_a_{j}"]] for j in JOINTS]).T
    for topic, message, ros in _decoded(log):
        if topic not in (GOAL, PRESENT, PLAN, FRAME):
            continue
        k = message.sequence
        stamp = ros.header.stamp.sec + 1e-9 * ros.header.stamp.nanosec
        assert stamp == pytest.approx(clock[k], abs=1e-9)
        assert message.log_time == round(clock[k] * 1e9)
        if topic == PRESENT:
            np.testing.assert_allclose(ros.effort, current[k] * KT_XM430, rtol=1e-12)
        if topic == PLAN:  # the plan_rad columns, or without them the goal sent
            prefix = "plan_rad" if "plan_rad_pan" in want else "goal_rad"
            plan = [float(want[f"{prefix}_{j}"][k]) for j in JOINTS]
            np.testing.assert_array_equal(ros.position, plan)


def test_report_and_stop_reason_are_in_the_log(excited):
    log, _, report = excited
    with open(log, "rb") as f:
        reader = make_reader(f)
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert {k: json.loads(v) for k, v in metadata["trajgen.report"].items()} == report
    layout = metadata["trajgen.telemetry"]
    assert json.loads(layout["effort_nm_per_a"]) == pytest.approx([KT_XM430] * 3, rel=1e-15)
    scale = "XM430-W350: Present Current, 2.69 mA per unit"
    assert json.loads(layout["current_scale"]) == [scale] * 3
    rosout = [ros for topic, _, ros in _decoded(log) if topic == "/rosout"]
    frames = report["stream"]["frames_sent"]
    assert f"stream completed: {frames}/{frames} frames sent" in [r.msg for r in rosout]
    assert {r.name for r in rosout} == {"trajgen"}


def test_identify_from_mcap_equals_identify_from_csv(excited):
    pytest.importorskip("mujoco.sysid", reason="needs mujoco[sysid]")
    from trajgen.sim.identify import identify, load_telemetry
    from trajgen.sim.model import gimbal_config_from_tables

    log, csv_path, _ = excited
    from_mcap, from_csv = load_telemetry(log), load_telemetry(csv_path)
    for name in ("t", "goal", "position", "velocity", "current"):
        np.testing.assert_allclose(
            getattr(from_mcap, name), getattr(from_csv, name), rtol=0, atol=1e-9, err_msg=name
        )
    assert from_mcap.rate_hz == pytest.approx(from_csv.rate_hz, abs=1e-9)
    kf = load_keyframe_file(log.parent / "k.toml")
    config = gimbal_config_from_tables(kf.tables, kf.path)
    fits = [identify(config, [data], max_iter=3) for data in (from_mcap, from_csv)]
    for joint in JOINTS:
        a, b = (fit.joints[joint].values for fit in fits)
        for p in a:
            assert a[p] == pytest.approx(b[p], abs=1e-9), (joint, p)


def _rows(n, rng, columns=None):
    """``n`` telemetry rows of random values by column (NaN where a read failed)."""
    columns = telemetry_columns(JOINTS) if columns is None else columns
    bookkeeping = {
        "frame": lambda k: k,
        "phase": lambda k: "approach" if k < 20 else "stream",
        "t_s": lambda k: 0.01 * k,
        "sent_s": lambda k: 0.01 * k,
        "lateness_s": lambda k: 1e-5,
        "clock_s": lambda k: 5 + 0.01 * k,
    }
    read = ("position_rad_", "velocity_rad_s_", "current_a_")
    rows = []
    for k in range(n):
        row = []
        for c in columns:
            if c in bookkeeping:
                row.append(bookkeeping[c](k))
            elif c.startswith("goal_tick_"):
                row.append(int(rng.integers(1000, 3000)))
            elif c.startswith(read) and k % 7 == 3:
                row.append(math.nan)
            else:
                row.append(float(rng.normal()))
        rows.append(row)
    return rows


def test_a_file_cut_anywhere_reads_up_to_its_last_whole_chunk(tmp_path, rng):
    from mcap.records import Chunk, Message
    from mcap.stream_reader import StreamReader, breakup_chunk

    path = tmp_path / "t.mcap"
    writer = TelemetryWriter(path, JOINTS)
    for row in _rows(1500, rng):
        writer.write(row)
    writer.close()
    full = read_columns(path)
    assert full["frame"].tolist() == list(range(1500))
    data = path.read_bytes()
    with open(path, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
        f.seek(0)
        in_chunk = [
            sum(isinstance(r, Message) for r in breakup_chunk(record))
            for record in StreamReader(f, emit_chunks=True).records
            if isinstance(record, Chunk)
        ]
    assert len(chunks) == len(in_chunk) > 20  # small chunks: little is lost to a kill
    messages = np.cumsum(in_chunk)
    for k in range(0, len(chunks) - 1, max(1, len(chunks) // 8)):
        end = chunks[k].chunk_start_offset + chunks[k].chunk_length
        end += chunks[k].message_index_length
        next_end = chunks[k + 1].chunk_start_offset + chunks[k + 1].chunk_length
        for cut in (end, end + 1, (end + next_end) // 2, next_end - 1):
            (tmp_path / "cut.mcap").write_bytes(data[:cut])
            contents = McapContents()
            got = read_columns(tmp_path / "cut.mcap", contents)
            assert not contents.complete
            # Exactly the frames whose four messages are in the whole chunks.
            n = len(got["frame"])
            assert n == messages[k] // 4, (k, cut)
            assert got["frame"].tolist() == list(range(n))
            for name in full:
                np.testing.assert_array_equal(got[name], full[name][:n], err_msg=name)


def test_plan_mcap_is_the_exact_plan(tmp_path):
    toml = _keyframes(tmp_path / "k.toml", seconds=1.6, rate=50)
    out = tmp_path / "plan.mcap"
    assert main(["plan", str(toml), "--out", str(out)]) == 0
    kf = load_keyframe_file(toml)
    spline = kf.spline()
    plan = plan_joint_trajectory(spline, 50.0)
    quats = spline.evaluate(plan.t, max_order=0).q
    messages = _decoded(out)
    (trajectory,) = [ros for t, _, ros in messages if t == "/trajgen/joint_trajectory"]
    assert trajectory.joint_names == JOINTS
    assert len(trajectory.points) == len(plan)
    for name, want in (("positions", plan.q), ("velocities", plan.qd), ("accelerations", plan.qdd)):
        got = np.array([getattr(p, name) for p in trajectory.points])
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12, err_msg=name)
    since = np.array(
        [p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec for p in trajectory.points]
    )
    np.testing.assert_allclose(since, plan.t - plan.t[0], rtol=0, atol=1e-9)
    orientation = [(m.sequence, ros) for t, m, ros in messages if t == "/trajgen/orientation"]
    assert [k for k, _ in orientation] == list(range(len(plan)))
    got = np.array(
        [[r.quaternion.w, r.quaternion.x, r.quaternion.y, r.quaternion.z] for _, r in orientation]
    )
    np.testing.assert_allclose(got, quats, rtol=0, atol=1e-12)
    states = [ros for t, _, ros in messages if t == PLAN]
    np.testing.assert_allclose([s.position for s in states], plan.q, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["pan_tilt_head.toml", "flex_roll_wrist.toml"])
def test_plan_mcap_of_other_axes_names_the_files_joints(tmp_path, name):
    from trajgen.jobs.stream_job import kinematics_of

    toml = Path(__file__).parents[1] / "examples" / name
    out = tmp_path / "plan.mcap"
    assert main(["plan", str(toml), "--out", str(out), "--rate", "50"]) == 0
    kf = load_keyframe_file(toml)
    kin = kinematics_of(kf)
    plan = plan_joint_trajectory(kf.spline(), 50.0, kin)
    messages = _decoded(out)
    (trajectory,) = [ros for t, _, ros in messages if t == "/trajgen/joint_trajectory"]
    assert trajectory.joint_names == list(kin.joints)
    got = np.array([p.positions for p in trajectory.points])
    np.testing.assert_allclose(got, plan.q, rtol=0, atol=1e-12)
    states = [ros for t, _, ros in messages if t == PLAN]
    assert states[0].name == list(kin.joints)
    np.testing.assert_allclose([s.velocity for s in states], plan.qd, rtol=0, atol=1e-12)


def _writer_children(pid):
    """Process ids of the MCAP writer processes started by ``pid``."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
            cmdline = Path(f"/proc/{entry}/cmdline").read_bytes()
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid and b"mcap_telemetry" in cmdline:
            found.append(int(entry))
    return found


def _gone(pid) -> bool:
    """Whether process ``pid`` has exited (a zombie counts as exited)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="finds the writer process in /proc")
@pytest.mark.parametrize("writer_too", [True, False], ids=["with its writer", "alone"])
def test_a_run_killed_mid_stream_leaves_a_readable_log(tmp_path, writer_too):
    toml = _keyframes(tmp_path / "long.toml", seconds=40.0, rate=100)
    log = tmp_path / "run.mcap"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "trajgen",
            "stream",
            str(toml),
            "--virtual",
            "--telemetry",
            str(log),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        while not (log.exists() and log.stat().st_size > 30_000):
            assert proc.poll() is None, proc.stderr.read().decode()
            try:
                proc.wait(0.05)
            except subprocess.TimeoutExpired:
                pass
        children = _writer_children(proc.pid)
        assert len(children) == 1
        # With its writer: everything dies at once, as on a power cut. Alone: the
        # writer process reads the end of its pipe and finishes the file.
        for pid in [proc.pid, *children] if writer_too else [proc.pid]:
            os.kill(pid, signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    for _ in range(6000):  # a bound for a writer that never ends (10 min), not a timing
        if _gone(children[0]):
            break
        time.sleep(0.1)
    assert _gone(children[0])
    contents = McapContents()
    got = read_columns(log, contents)
    assert contents.complete is not writer_too
    if not writer_too:
        with open(log, "rb") as f:
            assert make_reader(f).get_summary().statistics.message_count == 4 * len(got["frame"])
    n = len(got["frame"])
    assert n > 50
    assert got["frame"].tolist() == list(range(n))
    assert set(got["phase"].tolist()) <= {"approach", "lift", "stream"}
    assert np.all(np.diff(got["clock_s"]) > 0)


def test_the_core_and_the_drivers_load_without_mcap():
    code = (
        "import sys, trajgen, trajgen.telemetry_mcap, trajgen.plan_mcap, trajgen.drivers.telemetry;"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('mcap', 'mcap_ros2')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


@pytest.mark.parametrize(
    "argv",
    [
        ["stream", "--virtual", "--telemetry"],
        ["excite", "--virtual", "--telemetry"],
        ["plan", "--out"],
    ],
)
def test_a_missing_mcap_extra_is_named_before_anything_runs(argv, tmp_path, monkeypatch, capsys):
    import importlib.util

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util,
        "find_spec",
        lambda name, *a: None if name == "mcap_ros2" else find_spec(name, *a),
    )
    assert main(argv + [str(tmp_path / "x.mcap")]) == 2
    err = capsys.readouterr().err
    assert "needs the 'trajgen[mcap]' package: pip install 'trajgen[mcap]'" in err
    assert not (tmp_path / "x.mcap").exists()


def test_every_telemetry_column_has_a_place_in_the_run_log():
    from trajgen.telemetry_mcap import RowMessages

    RowMessages(telemetry_columns(JOINTS), JOINTS)  # all of them: no error
    with pytest.raises(ValueError, match="No MCAP field for telemetry column 'torque_nm_pan'"):
        RowMessages(telemetry_columns(JOINTS) + ["torque_nm_pan"], JOINTS)
    with pytest.raises(ValueError, match="Expected a telemetry column 'clock_s'"):
        RowMessages([c for c in telemetry_columns(JOINTS) if c != "clock_s"], JOINTS)


def test_a_log_that_cannot_be_written_is_said_at_close(tmp_path):
    writer = TelemetryWriter(tmp_path / "missing" / "t.mcap", JOINTS)
    writer.write(_rows(1, np.random.default_rng(0))[0])
    with pytest.warns(RuntimeWarning, match="telemetry .*t.mcap: .*No such file or directory"):
        writer.close()


def test_planned_columns_go_to_the_plan_topic(tmp_path, rng):
    from trajgen.drivers.mcap_telemetry import McapRunLog

    columns = telemetry_columns(JOINTS)
    columns += [f"plan_rad_{j}" for j in JOINTS if f"plan_rad_{j}" not in columns]
    rows = _rows(30, rng, columns)
    log = McapRunLog(tmp_path / "p.mcap", columns, JOINTS)
    for row in rows:
        log.write(row)
    log.close()
    got = read_columns(tmp_path / "p.mcap")
    assert list(got) == columns
    planned = [[r[columns.index(f"plan_rad_{j}")] for j in JOINTS] for r in rows]
    np.testing.assert_array_equal(np.column_stack([got[f"plan_rad_{j}"] for j in JOINTS]), planned)
    plans = [ros.position for t, _, ros in _decoded(tmp_path / "p.mcap") if t == PLAN]
    np.testing.assert_array_equal(plans, planned)


def test_the_foxglove_layout_shows_fields_the_run_log_has(excited):
    import re

    layout = json.loads((Path(__file__).parents[1] / "docs" / "foxglove_layout.json").read_text())

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    panels = leaves(layout["layout"])
    assert sorted(panels) == sorted(layout["configById"])
    assert {p.split("!")[0] for p in panels} == {"Plot", "RawMessages", "RosOut"}
    log, _, _ = excited
    last = {topic: ros for topic, _, ros in _decoded(log)}
    paths = [p["value"] for c in layout["configById"].values() for p in c.get("paths", ())]
    assert len(paths) == 16  # 3 joints x (goal, plan, present), effort, velocity, lateness
    for value in paths:
        topic, field, index = re.fullmatch(r"(/[\w/]+)\.(\w+)(?:\[(\d)\])?", value).groups()
        got = getattr(last[topic], field)
        got = got if index is None else got[int(index)]
        assert isinstance(got, float) and math.isfinite(got), value
    shown = [layout["configById"]["RawMessages!frame"]["topicPath"]]
    shown.append(layout["configById"]["RosOut!log"]["topicToRender"])
    assert shown == [FRAME, "/rosout"] and all(topic in last for topic in shown)


def test_faults_and_the_stop_reason_become_log_lines():
    from trajgen.drivers.mcap_telemetry import report_log
    from trajgen.ros2_messages import LOG_ERROR, LOG_INFO, LOG_WARN

    stream = {"frames_sent": 81, "frames_planned": 0, "stalls": 2, "delay_s": 0.0125}
    stream |= {"comm_errors": 3, "read_fallback": "no reply from servo 2"}
    report = {"status": 130, "stopped_by": "interrupted by SIGINT", "on_stop": "hold"}
    report |= {"stop_errors": ["servo 3: no status packet"], "stream": stream}
    assert report_log(report) == [
        (LOG_WARN, "read back by sync read: no reply from servo 2"),
        (LOG_WARN, "2 stalls; the stream ended 0.012500 s behind its plan"),
        (LOG_WARN, "3 failed transactions (retried or fatal)"),
        (LOG_ERROR, "safe stop: servo 3: no status packet"),
        (LOG_ERROR, "stopped by: interrupted by SIGINT (81 frames sent)"),
        (LOG_INFO, "exit status 130; servos: hold"),
    ]


def test_a_plan_too_long_for_one_message_is_refused(tmp_path, monkeypatch, capsys):
    from trajgen import plan_mcap

    monkeypatch.setattr(plan_mcap, "MAX_SAMPLES", 80)
    toml = _keyframes(tmp_path / "k.toml", seconds=0.8, rate=100)  # 81 samples
    out = tmp_path / "plan.mcap"
    assert main(["plan", str(toml), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"--out {out}: 81 samples; an MCAP plan is one JointTrajectory message" in err
    assert "at most 80 samples: lower --rate, or write CSV" in err
    assert not out.exists()
