"""Reports and Table 2 from recorded runs: every figure drawn, every column filled, bag metrics =
in-process metrics."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cikan_ros.analysis.report import write_report
from cikan_ros.analysis.table import COLUMNS, _runs, build_table, to_csv, to_markdown
from cikan_ros.montecarlo import run_campaign

FIGURES = ("fig3a_relative_vnb", "fig3a_relative_vnb_zoom", "fig3b_tau", "fig3c_mean_tau",
           "fig3d_distance", "fig3e_speed", "fig4_constraints")
REPO = Path(__file__).resolve().parents[1]
MODEL_COLUMNS = ("trainable_params", "paper_complexity", "loss_train_1e3", "loss_val_1e3",
                 "rmse_tau_s", "rmse_tau_active_s", "nn_accept_rate", "architecture")


def _assert_page(page: Path) -> None:
    """Every figure is linked from the page and is a PNG that decodes to an image."""
    import matplotlib.image

    text = page.read_text()
    for name in FIGURES:
        png = page.parent / f"{name}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert min(matplotlib.image.imread(png).shape[:2]) > 300, name
        assert f"]({name}.png)" in text


@dataclass
class Drawn:
    """What one saved figure plotted: per axes its labels and its lines (x, y, colour)."""

    axes: list[dict[str, Any]]

    def lines(self, ax: int = 0, n: int | None = None) -> list[tuple[np.ndarray, np.ndarray, str]]:
        """The data lines of axes ``ax`` (those with ``n`` points when given)."""
        return [ln for ln in self.axes[ax]["lines"] if n is None or len(ln[0]) == n]


@pytest.fixture
def drawn(monkeypatch) -> dict[str, Drawn]:
    """{figure name: Drawn} of every figure the report saves (the last one of a name)."""
    from matplotlib.colors import to_hex

    from cikan_ros.analysis import figures

    out: dict[str, Drawn] = {}
    save = figures._save

    def capture(fig, path):
        out[Path(path).stem] = Drawn([{
            "xlabel": ax.get_xlabel(), "ylabel": ax.get_ylabel(), "title": ax.get_title(), "xlim": ax.get_xlim(),
            "lines": [(np.asarray(ln.get_xdata(), dtype=float), np.asarray(ln.get_ydata(), dtype=float),
                       to_hex(ln.get_color())) for ln in ax.get_lines()]} for ax in fig.axes])
        return save(fig, path)

    monkeypatch.setattr(figures, "_save", capture)
    return out


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal to rounding of the largest value (the bag holds states in metres, the library km)."""
    scale = float(np.nanmax(np.abs(b))) if np.any(np.isfinite(b)) else 0.0
    return a.shape == b.shape and bool(np.allclose(a, b, rtol=1e-12, atol=1e-12 * scale, equal_nan=True))


def _assert_histories(drawn: dict[str, Drawn], runs: list[dict[str, np.ndarray]], colours: list[str]) -> None:
    """Fig. 3b, 3d, 3e, 3a, 4 plot each run's own histories (from its record, in the units the
    axes name) in its governor's colour; Fig. 3c each governor's mean over its runs."""
    n = len(runs[0]["t"])
    hours = (runs[0]["t"] - runs[0]["t"][0]) / 3600.0
    for name, ylabel, values in (
            ("fig3b_tau", "time shift τ (s)", [r["tau"] for r in runs]),
            ("fig3d_distance", "relative distance (km)",
             [np.sqrt(np.sum((r["x_d"][:, :3] - r["x_c"][:, :3]) ** 2, axis=1)) for r in runs]),
            ("fig3e_speed", "relative speed (m/s)",
             [1e3 * np.sqrt(np.sum((r["x_d"][:, 3:] - r["x_c"][:, 3:]) ** 2, axis=1)) for r in runs])):
        fig = drawn[name]
        assert (fig.axes[0]["xlabel"], fig.axes[0]["ylabel"]) == ("time (h)", ylabel)
        lines = fig.lines(0, n)
        assert len(lines) == len(runs), name
        for (x, y, colour), want, c in zip(lines, values, colours):
            assert _same(x, hours) and _same(y, want) and colour == c, name
    # Fig. 3a: per run, V (along the chief's velocity) against B and N; |V| <= |p_rel|, the
    # start behind the chief (V < 0), the end at the chief (docked: under 1 m)
    fig = drawn["fig3a_relative_vnb"]
    assert [a["ylabel"] for a in fig.axes[:2]] == ["B (km)", "N (km)"]
    for ax in (0, 1):
        lines = fig.lines(ax, n)
        assert len(lines) == len(runs)
        for (v, _, _), r in zip(lines, runs):
            dist = np.sqrt(np.sum((r["x_d"][:, :3] - r["x_c"][:, :3]) ** 2, axis=1))
            assert np.all(np.abs(v) <= dist + 1e-12 * dist.max()) and v[0] < -0.5 * dist[0] and abs(v[-1]) < 1e-3
    # Fig. 3c: each governor's mean tau over its runs
    fig = drawn["fig3c_mean_tau"]
    for colour in dict.fromkeys(colours):
        group = [r["tau"] for r, c in zip(runs, colours) if c == colour]
        (x, y, _), = [ln for ln in fig.lines(0, n) if ln[2] == colour]
        assert _same(x, hours) and _same(y, np.mean(group, axis=0))
    # Fig. 4: h1 normalised, h2 and h3 of one run (m/s^2, m/s), each with the red line h = 0
    fig = drawn["fig4_constraints"]
    assert [a["ylabel"] for a in fig.axes] == ["h1 / (|v_c||p_rel|)", "h2 = |u| - u_max (m/s²)", "h3 (m/s)"]
    (_, h1, _), = fig.lines(0, n)
    assert any(_same(h1, r["h1_normalised"]) for r in runs)
    for ax in range(3):
        assert any(c == "#d62728" and np.all(y == 0.0) for _, y, c in fig.lines(ax, 2))


@pytest.fixture(scope="module")
def campaign(tmp_path_factory, cfg):
    out = tmp_path_factory.mktemp("mc")
    run_campaign(cfg, ["conventional", "cikan"], runs=3, seed=1, out_dir=out, progress=False)
    return out


def test_table_has_every_column_filled(campaign):
    rows = build_table(campaign)
    assert [r["model"] for r in rows] == ["conventional", "cikan"]
    conv, cikan = rows
    for c in COLUMNS:
        assert cikan[c] is not None and not (isinstance(cikan[c], float) and math.isnan(cikan[c])), c
    for c in MODEL_COLUMNS:
        assert conv[c] is None  # the conventional TSG has no network
    assert conv["speedup_mean"] == 1.0 and cikan["runs"] == 3
    assert 0.0 <= cikan["nn_accept_rate"] <= 1.0 and cikan["rmse_tau_s"] >= 0.0
    # ΔV ratio of sums over the paired runs and its delta-method SE (Cochran), written out:
    # R = Σa/Σb, SE = sqrt(n/(n-1) Σ(a_i - R b_i)²) / Σb
    a, b = (np.array([json.loads(j.read_text())["metrics"]["delta_v_kmps"]
                      for j in sorted((campaign / g).glob("seed_*.json"))]) for g in ("cikan", "conventional"))
    r = a.sum() / b.sum()
    assert cikan["delta_v_vs_conventional"] == pytest.approx(r - 1.0, rel=1e-12, abs=1e-15)
    assert cikan["delta_v_vs_conventional_se"] == pytest.approx(
        math.sqrt(3 / 2 * np.sum((a - r * b) ** 2)) / b.sum(), rel=1e-12)
    md, csv = to_markdown(rows), to_csv(rows)
    assert "*paper: CIKAN (128,5,17)*" in md and "| **cikan**" in md
    assert f"± {100 * cikan['delta_v_vs_conventional_se']:.1f} %)" in md
    assert csv.splitlines()[0].split(",") == list(COLUMNS) and len(csv.splitlines()) == 3


def _rmse_by_hand(gov_dir: Path, predictor) -> tuple[float, float]:
    """SPEC §9 written out: at every update k of every stored run, the state the governor saw
    (step k P_upd/T_c, sent through SI: metres) and its tau_prev; pi* = the conventional TSG's
    answer there, 0 with no prediction when tau_prev = 0; RMSE = sqrt(mean((tau - pi*)^2)) over
    all updates and over those with tau_prev < 0."""
    err_all, err_active = [], []
    for npz in sorted(gov_dir.glob("seed_*.npz")):
        with np.load(npz) as a:
            for k, tau_prev, tau in zip(a["update_k"], a["update_tau_prev"], a["update_tau"]):
                step = int(k) * 6                                   # 60 s updates, 10 s steps
                x = a["x_d"][step] * 1000.0 / 1000.0
                star = predictor.optimal_shift(x, float(a["t"][step]), float(tau_prev))[0] if tau_prev < 0 else 0.0
                err_all.append(tau - star)
                if tau_prev < 0:
                    err_active.append(tau - star)
    return math.sqrt(np.mean(np.square(err_all))), math.sqrt(np.mean(np.square(err_active)))


def test_rmse_is_the_error_against_pi_star(campaign, predictor):
    """The table's RMSE of the learned governor equals SPEC §9's, computed here state by state."""
    cikan = build_table(campaign)[1]
    rmse_all, rmse_active = _rmse_by_hand(campaign / "cikan", predictor)
    assert rmse_active > 0.0
    assert cikan["rmse_tau_s"] == pytest.approx(rmse_all, rel=1e-12)
    assert cikan["rmse_tau_active_s"] == pytest.approx(rmse_active, rel=1e-12)


def test_rmse_of_known_errors(campaign, tmp_path):
    """Hand-computed: the conventional runs are their own pi* (RMSE 0); with the answers of two
    active updates moved by +0.3 s and -0.4 s and one update after tau = 0 by +1.2 s (states
    unchanged), RMSE = sqrt((0.09 + 0.16) / n_active) over active updates and
    sqrt((0.09 + 0.16 + 1.44) / n_all) over all of them."""
    from cikan_ros.analysis.table import rmse_against_optimal

    runs = tmp_path / "conventional"
    shutil.copytree(campaign / "conventional", runs)
    assert rmse_against_optimal(_runs(runs)) == (0.0, 0.0)
    npz = sorted(runs.glob("seed_*.npz"))[0]
    with np.load(npz) as data:
        a = {k: data[k] for k in data.files}
    active = np.flatnonzero(a["update_tau_prev"] < 0)
    idle = np.flatnonzero(a["update_tau_prev"] == 0)
    tau = a["update_tau"].copy()
    tau[active[0]] += 0.3
    tau[active[1]] -= 0.4
    tau[idle[0]] += 1.2
    np.savez_compressed(npz, **{**a, "update_tau": tau})
    n_all = sum(len(np.load(f)["update_tau"]) for f in runs.glob("seed_*.npz"))
    n_active = sum(int(np.sum(np.load(f)["update_tau_prev"] < 0)) for f in runs.glob("seed_*.npz"))
    rmse_all, rmse_active = rmse_against_optimal(_runs(runs))
    assert rmse_active == pytest.approx(math.sqrt(0.25 / n_active), rel=1e-9)
    assert rmse_all == pytest.approx(math.sqrt(1.69 / n_all), rel=1e-9)


def test_nn_accept_is_the_share_of_active_updates_the_network_decided(campaign, tmp_path):
    """Counted by hand from the stored decisions: updates with tau_prev != 0 whose path is "nn",
    over all such updates, pooled over the campaign's runs (Table 2 and the scenario index), and
    each run's own share in its metrics (the campaign summary's mean)."""
    from cikan_ros.analysis.table import scenarios_index

    accepted = active = 0
    shares = []
    for npz in sorted((campaign / "cikan").glob("seed_*.npz")):
        with np.load(npz) as a:
            run = [str(p) for p, prev in zip(a["update_path"], a["update_tau_prev"]) if prev != 0.0]
        accepted += run.count("nn")
        active += len(run)
        shares.append(run.count("nn") / len(run))
        stored = json.loads(npz.with_suffix(".json").read_text())["metrics"]["nn_accept_rate"]
        assert stored == pytest.approx(shares[-1], rel=1e-12)
    assert active > 0 and 0 < accepted < active
    row = build_table(campaign, with_rmse=False)[1]
    assert row["nn_accept_rate"] == pytest.approx(accepted / active, rel=1e-12)
    shutil.copytree(campaign, tmp_path / "paper-behind")   # the index reads a directory of campaigns
    index = scenarios_index(tmp_path)
    assert f"| paper | behind | nominal | cikan | 3 |" in index and f"| {accepted / active:.3f} |" in index


def test_starts_verify_refused_are_said_not_drawn(campaign, tmp_path):
    """A campaign where robust Verify refused a start (its JSON says why, no trajectory): the
    report flies on with the runs that flew and says how many starts each governor had refused."""
    mc = tmp_path / "mc"
    shutil.copytree(campaign, mc)
    stored = json.loads(next((mc / "conventional").glob("seed_*.json")).read_text())
    for g in ("conventional", "cikan"):
        (mc / g / "seed_00099.json").write_text(json.dumps({"config": stored["config"], "metrics": {
            "governor": g, "seed": 99, "refused": "no feasible time shift", "success": False}}))
    text = write_report(mc, tmp_path / "rep", figures=False).read_text()
    assert "Starts Verify refused (no feasible shift at the first instant: not flown, not in the table): " \
           "conventional 1 of 4, cikan 1 of 4." in text
    assert "| conventional | 3 | 3 | 0 |" in text


def test_report_from_a_montecarlo_directory(campaign, tmp_path, drawn):
    page = write_report(campaign, tmp_path / "rep")
    _assert_page(page)
    runs = [dict(np.load(f)) for g in ("conventional", "cikan") for f in sorted((campaign / g).glob("seed_*.npz"))]
    _assert_histories(drawn, runs, ["#000000"] * 3 + ["#1f77b4"] * 3)
    assert (tmp_path / "rep" / "table2.csv").exists()
    assert "| conventional | 3 | 3 | 0 |" in page.read_text()


BAG = REPO / "bags" / "nominal_conventional"
TIMING = {"initial_ms", "update_ms_mean", "update_ms_max", "active_update_ms_mean", "active_update_ms_max",
          "update_cpu_ms_mean", "update_cpu_ms_max", "active_update_cpu_ms_mean", "active_update_cpu_ms_max"}


def test_report_from_the_committed_bag(tmp_path, drawn):
    """`cikan report` on the reference bag (a lockstep ROS run, read with rosbags) draws every
    figure from the bag's own record."""
    page = write_report(BAG, tmp_path / "bag")
    _assert_page(page)
    b = _bag_record(BAG)
    n = len(b["t"])
    tau = np.full(n, np.nan)
    tau[np.searchsorted(b["t"], b["t_shift"])] = b["tau"]     # in force from its stamp; none at the end
    tau[-1] = tau[-2]
    run = {"t": b["t"], "x_d": b["x_d"] * 1e-3, "x_c": b["x_c"] * 1e-3, "tau": tau,
           "h1_normalised": drawn["fig4_constraints"].lines(0, n)[0][1]}
    _assert_histories(drawn, [run], ["#000000"])
    assert "| docked with zero violations | True |" in page.read_text()


def _bag_record(bag: Path) -> dict[str, np.ndarray]:
    """The reference bag's messages decoded with mcap_ros2 alone (not cikan_ros's reader), SI units,
    one row per message in stamp order: t (s since the first stamp), chief and deputy [r; v],
    the time shift (time_ref - stamp, s) and the commanded acceleration."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    def ns(t: Any) -> int:
        return t.sec * 10**9 + t.nanosec

    rows: dict[str, list] = {"/chief/odom": [], "/deputy/odom": [], "/tsg/time_shift": [], "/deputy/accel_cmd": []}
    with open(next(bag.glob("*.mcap")), "rb") as f:
        for _, channel, _, msg in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            if channel.topic.endswith("/odom"):
                p, v = msg.pose.pose.position, msg.twist.twist.linear
                rows[channel.topic].append((ns(msg.header.stamp), [p.x, p.y, p.z, v.x, v.y, v.z]))
            elif channel.topic == "/tsg/time_shift":
                rows[channel.topic].append((ns(msg.header.stamp), (ns(msg.time_ref) - ns(msg.header.stamp)) / 1e9))
            elif channel.topic == "/deputy/accel_cmd":
                a = msg.accel.linear
                rows[channel.topic].append((ns(msg.header.stamp), [a.x, a.y, a.z]))
    out = {topic: sorted(r, key=lambda x: x[0]) for topic, r in rows.items()}
    t0 = out["/chief/odom"][0][0]
    assert [s for s, _ in out["/chief/odom"]] == [s for s, _ in out["/deputy/odom"]]
    return {"t": np.array([(s - t0) / 1e9 for s, _ in out["/chief/odom"]]),
            "x_c": np.array([x for _, x in out["/chief/odom"]]),
            "x_d": np.array([x for _, x in out["/deputy/odom"]]),
            "t_shift": np.array([(s - t0) / 1e9 for s, _ in out["/tsg/time_shift"]]),
            "tau": np.array([x for _, x in out["/tsg/time_shift"]]),
            "u": np.array([x for _, x in out["/deputy/accel_cmd"]])}


def test_bag_metrics_are_what_the_bag_records():
    """Metrics rebuilt from the bag equal the figures written out here from its raw messages
    (SPEC §4, §6, §9, SI units; the paper's cone alpha = 20 deg with the port facing -v_c, h3 with
    gamma = 5 km, 20 /s, 1 mm/s): everything they state is determined by the bag itself."""
    from cikan_ros.analysis.report import run_from_bag

    _, m = run_from_bag(BAG)
    b = _bag_record(BAG)
    rel = b["x_d"] - b["x_c"]
    p, v = rel[:, :3], rel[:, 3:]
    dist, speed = np.linalg.norm(p, axis=1), np.linalg.norm(v, axis=1)
    vc = np.linalg.norm(b["x_c"][:, 3:], axis=1)
    out = dist > 1.0                                          # the cone apex radius, 1 m
    h1n = (np.einsum("ij,ij->i", b["x_c"][out, 3:], p[out]) + math.cos(math.radians(20.0)) * vc[out] * dist[out]) \
        / (vc[out] * dist[out])
    near = dist <= 5000.0
    h3 = (speed[near] - 20.0 * dist[near] - 1.0) * 1e-3      # km/s
    dv = 10.0 * np.linalg.norm(b["u"], axis=1).sum() * 1e-3  # km/s: T_c sum |u_k|
    at_dock = (dist < 1.0) & (speed < 1e-3)
    assert m["delta_v_kmps"] == pytest.approx(dv, rel=1e-12)
    # positions of ~7e6 m carry ~1e-9 m of rounding (the library works in km), speeds ~1e-12 m/s
    assert m["final_distance_m"] == pytest.approx(dist[-1], abs=1e-8)
    assert m["final_speed_mps"] == pytest.approx(speed[-1], abs=1e-10)
    assert m["min_h1_margin"] == pytest.approx(-h1n.max(), rel=1e-6, abs=1e-12)
    assert m["max_h3"] == pytest.approx(h3.max(), rel=1e-9)
    assert m["violations"] == int(np.count_nonzero(h1n > 1e-9) + np.count_nonzero(h3 > 1e-9)) == 0
    assert m["tau0_s"] == b["tau"][0]
    assert m["t_tau_zero_s"] == b["t_shift"][np.argmax(b["tau"] == 0.0)]
    assert m["t_docked_s"] == b["t"][np.argmax(at_dock)]
    assert m["duration_s"] == b["t"][-1] == 14400.0
    assert m["updates"] == 14400 // 60 - 1                   # every 60 s after the first instant, before the end
    assert m["active_updates"] == int(np.count_nonzero(
        [b["tau"][b["t_shift"] == t - 10.0][0] < 0 for t in np.arange(60.0, 14400.0, 60.0)]))
    assert m["success"] is bool(at_dock[-1] and b["tau"][-1] == 0.0)


def test_report_on_a_bag_does_not_import_rclpy(tmp_path):
    """`cikan report BAG` (the bag reader, the rebuilt run and its metrics) in a fresh interpreter
    never imports rclpy: a bag is read without a ROS graph's runtime."""
    code = ("import sys\nfrom cikan_ros.cli import main\n"
            f"rc = main(['report', {str(BAG)!r}, '--out', {str(tmp_path)!r}, '--tables-only'])\n"
            "print('rclpy loaded:', 'rclpy' in sys.modules)\nsys.exit(rc)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert "rclpy loaded: False" in run.stdout
    assert "| docked with zero violations | True |" in (tmp_path / "report.md").read_text()


def test_bag_decisions_agree_with_the_in_process_governor(predictor):
    """The bag was recorded on another processor: the in-process conventional TSG, given each
    recorded update state (deputy, time, previous shift), answers what the bag's governor did to
    within the window where Verify switches between feasible and infeasible (SPEC §5, §10: within
    +-0.2 s of the answer), and the in-process mission from the same start keeps the same
    contract: tau_0 within that window, docked, no violation. Whole trajectories are compared
    nowhere: a last-bit difference sends the closed loop another way (a 1-cm change of the start
    moved tau by 1.8 s and Delta-V by 16 %, measured)."""
    from cikan_ros.analysis.report import run_from_bag
    from cikan_ros.governor import ConventionalGovernor
    from cikan_ros.mission import nominal_start, run_mission

    window = 0.2
    b = _bag_record(BAG)
    checked = 0
    for t in np.arange(60.0, 14400.0, 60.0):
        tau_prev, tau = b["tau"][b["t_shift"] == t - 10.0][0], b["tau"][b["t_shift"] == t][0]
        if tau_prev == 0.0:
            continue
        x = b["x_d"][b["t"] == t][0] * 1e-3                  # km, km/s
        mine, _ = predictor.optimal_shift(x, float(t), float(tau_prev))
        assert tau_prev <= mine <= 0.0 and abs(mine - tau) <= window, (t, tau_prev, tau, mine)
        checked += 1
    assert checked == run_from_bag(BAG)[1]["active_updates"] > 10
    offline = run_mission(ConventionalGovernor(predictor), nominal_start(predictor)).metrics()
    assert abs(offline["tau0_s"] - b["tau"][0]) <= window
    assert offline["success"] and offline["violations"] == 0


def test_bag_carries_its_configuration_and_governor():
    """The recorder stores the mission's configuration and governor in metadata.yaml custom_data."""
    from cikan_ros.ros.bag_reader import bag_config, bag_governor
    from cikan_ros.config import load_config

    assert bag_config(BAG, None) == load_config()
    assert bag_governor(BAG) == "conventional"


def test_metrics_from_the_typed_topics_alone(tmp_path, cfg):
    """A copy of the reference bag without /diagnostics (what any governor keeping the topic
    contract leaves): the same run and metrics, decision timings unknown (None), audit clean."""
    import yaml
    from mcap.reader import make_reader

    from cikan_ros.ros.bag_writer import BagWriter
    from cikan_ros.ros.bag_reader import recorded_metrics

    typed = tmp_path / "typed"
    writer = BagWriter(typed)
    meta = yaml.safe_load((BAG / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    qos = {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
           for t in meta["topics_with_message_count"]}
    with open(next(BAG.glob("*.mcap")), "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.topic != "/diagnostics":
                writer.add_topic(channel.topic, schema.name, qos[channel.topic])
                writer.write(channel.topic, message.data, message.log_time)
    writer.close()
    full_run, full = recorded_metrics(BAG, cfg, "conventional")
    run, metrics = recorded_metrics(typed, cfg, "conventional")
    np.testing.assert_array_equal(run.tau, full_run.tau)
    np.testing.assert_array_equal(run.u, full_run.u)         # the applied commands
    np.testing.assert_array_equal(run.x_d, full_run.x_d)
    assert [r.path for r in run.updates] == [r.path for r in full_run.updates]
    for key, value in full.items():
        if key in TIMING or key in ("verify_calls", "active_verify_calls_max"):
            assert metrics[key] is None, key
        elif key != "ros":
            assert metrics[key] == value, key
    assert "ros" not in metrics and "ros" in full               # the simulator's summary is an extra
    assert (metrics["unverified_shifts"], metrics["off_schedule_shifts"], metrics["missing_shifts"]) == (0, 0, 0)


NARROW_AHEAD = """\
/**:
  ros__parameters:
    scenario:
      name: "narrow"
      description: "the paper's orbit, a 15-degree cone, from ahead"
    constraints:
      los_half_angle_deg: 15.0
    mission:
      approach: "ahead"
      duration_s: 3600.0
"""


def test_figures_draw_the_cone_and_side_the_run_flew(tmp_path, drawn):
    """A custom scenario (a file) with a 15-degree cone, from ahead: Fig. 3a's cone edges leave the
    chief along +V (the port faces the approach) with slope tan 15 deg, the axes hold the whole
    approach on the +V side, and report.md names the scenario and the side."""
    from cikan_ros.config import load_config, scenario_overrides

    scenario = tmp_path / "narrow.yaml"
    scenario.write_text(NARROW_AHEAD)
    cfg = load_config(**scenario_overrides(str(scenario)))
    run_campaign(cfg, ["conventional"], runs=1, seed=1, out_dir=tmp_path / "mc")
    page = write_report(tmp_path / "mc", tmp_path / "rep")
    orange = "#ff7f0e"
    x_d = np.load(next((tmp_path / "mc" / "conventional").glob("seed_*.npz")))["x_d"]
    for name in ("fig3a_relative_vnb", "fig3a_relative_vnb_zoom"):
        for ax in drawn[name].axes[:2]:
            edges = [(x, y) for x, y, c in ax["lines"] if c == orange and len(x) == 2]
            assert len(edges) == 2, name
            for x, y in edges:
                assert x[0] == 0.0 and y[0] == 0.0 and x[1] > 0.0                   # from the chief along +V
                assert abs(y[1] / x[1]) == pytest.approx(math.tan(math.radians(15.0)), rel=1e-12)
            assert {np.sign(y[1]) for _, y in edges} == {-1.0, 1.0}
            lo, hi = ax["xlim"]
            assert lo < 0.0 < hi and hi > -lo          # the axes open on the +V side
    assert "15°" in drawn["fig4_constraints"].axes[0]["title"]
    # the whole approach is inside the axes: V of the start (km) below the right limit
    start_v = drawn["fig3a_relative_vnb"].lines(0, len(x_d))[0][0][0]
    assert 0.0 < start_v < drawn["fig3a_relative_vnb"].axes[0]["xlim"][1]
    text = page.read_text()
    assert "scenario: narrow" in text and "from ahead (τ >= 0, cone 15° around +v_c)" in text


def test_h2_is_drawn_against_the_limit_it_is_judged_by(cfg, tmp_path, drawn):
    """Under a truth with a thruster bias bound b, h2 = |u| - u_max (1 + b): Fig. 4 names that
    limit and scales its axis to it."""
    from cikan_ros.analysis.figures import RunData, constraint_histories
    from cikan_ros.config import truth_overrides

    real = cfg.replace(**truth_overrides("realistic"))
    limit_mps2 = 1e3 * real.control.u_max_kmps2 * (1.0 + real.truth.scale * real.truth.thrust_bias_max)
    n = 5
    x_c = np.tile([7000.0, 0.0, 0.0, 0.0, 7.5, 0.0], (n, 1))
    run = RunData("conventional", np.arange(n) * 10.0, x_c + [0, -1, 0, 0, 0, 0], x_c, np.zeros((n, 3)),
                  np.zeros(n), np.full(n, -0.5), np.full(n, -limit_mps2 / 1e3), np.full(n, np.nan), real)
    constraint_histories([run], tmp_path / "fig4.png")
    ax = drawn["fig4"].axes[1]
    assert ax["ylabel"] == "h2 = |u| - u_lim (m/s²)"
    assert f"u_lim = {limit_mps2:.6g} m/s²" in ax["title"] and limit_mps2 == pytest.approx(0.51)


def test_metrics_json_is_strict_json(campaign, tmp_path):
    """A value a run could not compute (NaN in its stored metrics, as Python's json writes it) is
    null in report's metrics.json, which any strict JSON reader parses."""
    mc = tmp_path / "mc"
    shutil.copytree(campaign, mc)
    first = sorted((mc / "conventional").glob("seed_*.json"))[0]
    stored = json.loads(first.read_text())
    stored["metrics"]["update_ms_max"] = math.nan
    first.write_text(json.dumps(stored))
    assert "NaN" in first.read_text()
    write_report(mc, tmp_path / "rep", figures=False)

    def refuse(name: str) -> None:
        raise ValueError(f"not strict JSON: {name}")

    metrics = json.loads((tmp_path / "rep" / "metrics.json").read_text(), parse_constant=refuse)
    assert metrics[0]["update_ms_max"] is None


def _report(capsys, *args: str) -> tuple[int, str]:
    """``cikan report ARGS``: (exit code, stderr)."""
    from cikan_ros.cli import main

    rc = main(["report", *args])
    return rc, capsys.readouterr().err


def test_report_on_a_truncated_bag_is_partial_and_says_so(tmp_path, capsys):
    """A bag whose MCAP file was cut in half (no summary, no end magic): the report holds what
    is readable, up to the last step with every state, and says what is missing."""
    bag = tmp_path / "cut"
    shutil.copytree(BAG, bag)
    mcap = next(bag.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    rc, err = _report(capsys, str(bag), "--out", str(tmp_path / "rep"), "--tables-only")
    assert rc == 0 and "Traceback" not in err
    assert err.count("\n") == 1 and "partial report: the bag is damaged (File end magic is invalid)" in err
    m, = json.loads((tmp_path / "rep" / "metrics.json").read_text())
    assert "the rest is missing" in m["partial"] and 0 < m["duration_s"] < 14400.0
    assert "**Partial report** of `cut`" in (tmp_path / "rep" / "report.md").read_text()


def test_report_on_a_bag_cut_before_any_step_is_one_line(tmp_path, capsys):
    bag = tmp_path / "stub"
    shutil.copytree(BAG, bag)
    mcap = next(bag.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[:200])
    rc, err = _report(capsys, str(bag), "--out", str(tmp_path / "rep"))
    assert rc == 2 and err.count("\n") == 1 and "is unreadable" in err and "Traceback" not in err


def test_report_on_the_mcap_file_is_the_bags_report(tmp_path, capsys):
    """The bag's .mcap file given in place of its directory: the report of the bag; any other
    file: one line, exit code 2."""
    rc, _ = _report(capsys, str(next(BAG.glob("*.mcap"))), "--out", str(tmp_path / "file"), "--tables-only")
    assert rc == 0
    _report(capsys, str(BAG), "--out", str(tmp_path / "dir"), "--tables-only")
    assert (tmp_path / "file" / "report.md").read_text() == (tmp_path / "dir" / "report.md").read_text()
    rc, err = _report(capsys, str(BAG / "metadata.yaml"), "--out", str(tmp_path / "x"))
    assert rc == 2 and err.count("\n") == 1 and "is a file" in err


def test_the_scenario_index_keeps_the_rows_of_worlds_not_flown_here(campaign, tmp_path):
    """`make scenario-index` with one world's runs on the machine: that world's rows come from its
    runs (and are kept in its page's index_rows.md), every other world's from the rows kept beside
    its page at its last flight, in world order, and the page says which were kept; a world flown
    again replaces its kept rows."""
    from cikan_ros.analysis.table import INDEX_ROWS, campaign_rows, scenarios_index

    runs, pages = tmp_path / "runs", tmp_path / "pages"
    shutil.copytree(campaign, runs / "paper-behind")
    (pages / "leo-ahead").mkdir(parents=True)
    kept = "| leo | ahead | nominal | conventional | 100 | 100 | 0 | 5 | 0.8941 | - | - | 1.00 / 1.00 | - |"
    (pages / "leo-ahead" / INDEX_ROWS).write_text(kept + "\n")
    fresh = campaign_rows(runs / "paper-behind")
    assert len(fresh) == 2   # the campaign fixture: the conventional TSG and cikan
    lines = scenarios_index(runs, pages).splitlines()
    assert lines[2:3 + len(fresh)] == [kept] + fresh        # leo-ahead sorts before paper-behind
    assert (pages / "paper-behind" / INDEX_ROWS).read_text().splitlines() == fresh
    said = [line for line in lines if line.startswith("Rows of ")]
    assert len(said) == 1 and "leo-ahead" in said[0] and "paper-behind" not in said[0]
    shutil.copytree(campaign, runs / "leo-ahead")             # flown again
    lines = scenarios_index(runs, pages).splitlines()
    assert kept not in lines and not any(line.startswith("Rows of ") for line in lines)
    assert (pages / "leo-ahead" / INDEX_ROWS).read_text().splitlines() == fresh
