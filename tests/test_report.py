"""Reports and Table 2 from recorded runs: every figure drawn, every column filled, bag metrics =
in-process metrics."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cikan_ros.analysis.report import write_report
from cikan_ros.analysis.paired import paired_ratio
from cikan_ros.analysis.table import COLUMNS, _runs, build_table, to_csv, to_markdown
from cikan_ros.montecarlo import run_campaign

FIGURES = ("fig3a_relative_vnb", "fig3a_relative_vnb_zoom", "fig3b_tau", "fig3c_mean_tau",
           "fig3d_distance", "fig3e_speed", "fig4_constraints")
REPO = Path(__file__).resolve().parents[1]
MODEL_COLUMNS = ("trainable_params", "paper_complexity", "loss_train_1e3", "loss_val_1e3",
                 "rmse_tau_s", "rmse_tau_active_s", "nn_accept_rate", "architecture")


def _assert_page(page: Path) -> None:
    text = page.read_text()
    for name in FIGURES:
        png = page.parent / f"{name}.png"
        assert png.exists() and png.stat().st_size > 10_000, name  # a drawn figure, not an empty canvas
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"]({name}.png)" in text


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
    dv = {g: [m["delta_v_kmps"] for m, _, _ in _runs(campaign / g)] for g in ("cikan", "conventional")}
    assert cikan["delta_v_vs_conventional_se"] == paired_ratio(dv["cikan"], dv["conventional"]).se
    md, csv = to_markdown(rows), to_csv(rows)
    assert "*paper: CIKAN (128,5,17)*" in md and "| **cikan**" in md
    assert f"± {100 * cikan['delta_v_vs_conventional_se']:.1f} %)" in md
    assert csv.splitlines()[0].split(",") == list(COLUMNS) and len(csv.splitlines()) == 3


def test_rmse_is_zero_for_the_conventional_answers(campaign, cfg):
    """Sanity of the RMSE machinery: pi* at the conventional governor's own states is its answer."""
    from cikan_ros.analysis.table import rmse_against_optimal

    rmse_all, rmse_active, _ = rmse_against_optimal(_runs(campaign / "conventional"))
    assert rmse_all == 0.0 and rmse_active == 0.0


def test_report_from_a_montecarlo_directory(campaign, tmp_path):
    page = write_report(campaign, tmp_path / "rep")
    _assert_page(page)
    assert (tmp_path / "rep" / "table2.csv").exists()
    assert "| conventional | 3 | 3 | 0 |" in page.read_text()


BAG = REPO / "bags" / "nominal_conventional"
TIMING = {"initial_ms", "update_ms_mean", "update_ms_max", "active_update_ms_mean", "active_update_ms_max",
          "update_cpu_ms_mean", "update_cpu_ms_max", "active_update_cpu_ms_mean", "active_update_cpu_ms_max"}


def test_report_from_the_committed_bag(tmp_path):
    """`cikan report` on the reference bag (a lockstep ROS run, read with rosbags) draws every figure."""
    page = write_report(BAG, tmp_path / "bag")
    _assert_page(page)
    assert "| success | True |" in page.read_text()


def test_report_on_a_bag_does_not_import_rclpy(tmp_path):
    """`cikan report BAG` (the bag reader, the rebuilt run and its metrics) in a fresh interpreter
    never imports rclpy: a bag is read without a ROS graph's runtime."""
    code = ("import sys\nfrom cikan_ros.cli import main\n"
            f"rc = main(['report', {str(BAG)!r}, '--out', {str(tmp_path)!r}, '--tables-only'])\n"
            "print('rclpy loaded:', 'rclpy' in sys.modules)\nsys.exit(rc)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert "rclpy loaded: False" in run.stdout
    assert "| success | True |" in (tmp_path / "report.md").read_text()


def test_bag_metrics_equal_the_in_process_metrics(predictor):
    """Metrics rebuilt from the bag equal those of the same mission flown in-process (offline loop):
    counts and shifts exactly, physical figures to rounding (the bag holds states in metres)."""
    from cikan_ros.analysis.report import run_from_bag
    from cikan_ros.governor import ConventionalGovernor
    from cikan_ros.mission import nominal_start, run_mission

    run, from_bag = run_from_bag(BAG)
    offline = run_mission(ConventionalGovernor(predictor), nominal_start(predictor))
    in_process = offline.metrics()
    np.testing.assert_array_equal(run.tau, offline.tau)
    for key, value in in_process.items():
        if key in TIMING:
            continue
        if isinstance(value, float) and key not in ("tau0_s", "t_tau_zero_s", "t_docked_s", "duration_s"):
            # States cross the bag in metres: ~1e-16 relative of 7000 km is ~1e-9 m absolute.
            tol = 1e-6 if key.endswith(("_m", "_mps")) else 1e-9
            assert from_bag[key] == pytest.approx(value, rel=1e-9, abs=tol), key
        else:
            assert from_bag[key] == value, key


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
