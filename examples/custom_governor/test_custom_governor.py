"""The governors of this directory flown in place of governor_node, the way docs/governor_contract.md says:
`cikan mission --governor-exec "python <file>"` (real processes, real DDS, a private domain).

The bag is read back with rosbags (an independent reader), the constraints rechecked with numpy.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
CIKAN = Path(sys.executable).parent / "cikan"


def fly(tmp_path: Path, governor: str, *args: str) -> subprocess.CompletedProcess:
    """`cikan mission --governor-exec "python governor"` recorded to tmp_path/bag."""
    env = {**os.environ, "ROS_LOG_DIR": str(tmp_path / "log"),
           "TMPDIR": str(tmp_path)}
    return subprocess.run([str(CIKAN), "mission", "--governor-exec", f"{sys.executable} {HERE / governor}",
                           "--bag", str(tmp_path / "bag"), *args], capture_output=True, text=True, env=env)


def bag_messages(bag: Path) -> dict[str, list]:
    from rosbags.highlevel import AnyReader

    out: dict[str, list] = {}
    with AnyReader([bag]) as reader:
        for conn, _, raw in reader.messages():
            out.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    return out


def stamp(msg) -> int:
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


def h1_violations(msgs: dict[str, list], alpha_deg: float = 20.0) -> int:
    """Steps whose deputy lies outside the LoS cone (SPEC §4 h1 > 0, normalised, beyond 1 m)."""
    def states(topic: str) -> np.ndarray:
        pairs = sorted((stamp(m), [m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z,
                                   m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.linear.z])
                       for m in msgs[topic])
        return np.array([x for _, x in pairs]) / 1000.0
    x_d, x_c = states("/deputy/odom"), states("/chief/odom")
    p, vc = x_d[:, :3] - x_c[:, :3], x_c[:, 3:]
    pn, vn = np.linalg.norm(p, axis=1), np.linalg.norm(vc, axis=1)
    h1n = (np.sum(vc * p, axis=1) + np.cos(np.radians(alpha_deg)) * vn * pn) / (vn * pn)
    return int(np.count_nonzero((h1n > 1e-9) & (pn > 1e-3)))


def test_custom_governor_docks_with_the_optimal_shifts(tmp_path: Path) -> None:
    from cikan_ros.config import load_config
    from cikan_ros.governor import ConventionalGovernor
    from cikan_ros.mission import nominal_start, run_mission
    from cikan_ros.tsg import Predictor

    done = fly(tmp_path, "governor.py", "--json")
    assert done.returncode == 0, done.stderr
    metrics = json.loads(done.stdout)
    assert metrics["success"] and metrics["violations"] == 0
    assert metrics["governor"].startswith("exec:") and metrics["governor"].endswith("governor.py")
    assert (metrics["unverified_shifts"], metrics["off_schedule_shifts"], metrics["missing_shifts"]) == (0, 0, 0)
    assert metrics["update_ms_max"] is None           # no decision records: only the typed topics
    msgs = bag_messages(tmp_path / "bag")
    assert not any(st.name == "governor_node" for arr in msgs["/diagnostics"] for st in arr.status)
    assert {m.source for m in msgs["/tsg/time_shift"]} == {"custom:first", "custom:pi*", "hold"}
    # It computes pi* as the built-in conventional governor does: the same shift at every step.
    pred = Predictor.from_config(load_config())
    offline = run_mission(ConventionalGovernor(pred), nominal_start(pred))
    epoch = msgs["/deputy/odom"][0].header.stamp.sec * 10**9 + msgs["/deputy/odom"][0].header.stamp.nanosec
    taus = {(stamp(m) - epoch) // 10**10: (m.time_ref.sec * 10**9 + m.time_ref.nanosec - stamp(m)) / 1e9
            for m in msgs["/tsg/time_shift"]}
    assert sorted(taus) == list(range(len(offline.t) - 1))
    np.testing.assert_array_equal([taus[k] for k in sorted(taus)], offline.tau[:-1])
    assert metrics["tau0_s"] == offline.tau[0] and metrics["t_docked_s"] == offline.metrics()["t_docked_s"]


def test_rogue_governor_is_flown_to_the_end_and_its_violations_reported(tmp_path: Path) -> None:
    done = fly(tmp_path, "rogue_governor.py")          # the human-readable summary
    assert done.returncode == 1, done.stderr           # an unsuccessful mission, not an error (2)
    assert "Traceback" not in done.stderr
    rows = {line.split("│")[1].strip(): line.split("│")[2].strip()
            for line in done.stdout.splitlines() if line.count("│") == 3}
    msgs = bag_messages(tmp_path / "bag")
    assert {m.source for m in msgs["/tsg/time_shift"]} == {"rogue"}
    assert all(m.time_ref == m.header.stamp for m in msgs["/tsg/time_shift"])
    h1_bad = h1_violations(msgs)
    assert h1_bad > 0
    assert rows["docked with zero violations"] == "False"
    assert int(rows["control steps with a violation"]) >= h1_bad
    decisions = 1 + (len(msgs["/deputy/odom"]) - 2) // 6   # k = 0, then every P_upd / T_c = 6 steps
    assert rows["time shifts not verified (audit)"] == str(decisions)
    # `cikan report` rebuilds the same metrics from the bag's typed topics.
    report = subprocess.run([str(CIKAN), "report", str(tmp_path / "bag"), "--out", str(tmp_path / "report")],
                            capture_output=True, text=True)
    assert report.returncode == 0, report.stderr
    (metrics,) = json.loads((tmp_path / "report" / "metrics.json").read_text())
    assert metrics["violations_h1"] == h1_bad
    assert str(metrics["violations"]) == rows["control steps with a violation"]
    assert metrics["unverified_shifts"] == decisions and not metrics["success"]
