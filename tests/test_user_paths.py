"""Commands as users run them that no other test takes: a Monte Carlo campaign of a learned
governor on two worker processes, `cikan compare` and `cikan report --tables-only` /
`--scenarios` on it, `cikan train --like`, `cikan models`, and `cikan soak --load` with a
mission that fails. Short missions (20 minutes of a 4-hour one); every expectation is computed
here from what the command wrote (per-run JSON and arrays, model cards), from a committed page,
or from another way to the same runs (one mission at a time in this process), never by the code
under test."""

from __future__ import annotations

import csv
import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from cikan_ros.cli import main
from cikan_ros.config import load_config
from cikan_ros.registry import make_governor
from cikan_ros.learn.modelfile import MODELS_DIR
from cikan_ros.mission import run_mission, sample_start
from cikan_ros.tsg import Predictor
from ros_helpers import ros_env

__all__ = ["ros_env"]

SHORT = ["--set", "mission.duration_s=1200"]
GOVERNORS = ("conventional", "cikan")
SEEDS = (1, 2, 3)   # three runs of each governor on two workers: a worker flies one governor twice
REPO = Path(__file__).resolve().parents[1]


def timing(key: str) -> bool:
    """A wall- or CPU-time figure (differs from run to run)."""
    return key.endswith("_ms") or "_ms_" in key


def runs_of(campaign: Path, governor: str) -> list[dict]:
    """The per-run metrics `cikan montecarlo` wrote for a governor, by seed."""
    return [json.loads((campaign / governor / f"seed_{s:05d}.json").read_text())["metrics"] for s in SEEDS]


@pytest.fixture(scope="module")
def campaign(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`cikan montecarlo --governor conventional,cikan --runs 3 --workers 2` (20-minute missions),
    in a directory laid out as `make scenario-results` lays them out: <root>/paper-behind."""
    out = tmp_path_factory.mktemp("scenario-results") / "paper-behind"
    assert main(["montecarlo", "--governor", ",".join(GOVERNORS), "--runs", str(len(SEEDS)), "--seed",
                 str(SEEDS[0]), "--workers", "2", "--out", str(out), "--json", *SHORT]) == 0
    return out


def test_montecarlo_on_two_workers_flies_the_missions_flown_one_by_one(campaign: Path) -> None:
    """Each run of the two worker processes (governors made once per process and reused from
    run to run) is the mission flown alone from the same seed in this process: the same
    metrics (timings aside) and the same trajectory."""
    from cikan_ros.montecarlo import load_run_arrays

    cfg = load_config(**{"mission.duration_s": 1200.0})
    pred = Predictor.from_config(cfg)
    for name in GOVERNORS:
        for seed, stored in zip(SEEDS, runs_of(campaign, name)):
            gov = make_governor(name, cfg, pred)      # a new governor for each mission
            alone = run_mission(gov, sample_start(gov.predictor, seed), seed)
            expected = {k: v for k, v in alone.metrics().items() if not timing(k)}
            if name != "conventional":   # a learned governor's runs also say how often its network was taken
                from cikan_ros.learn.governor import nn_accept_rate

                expected["nn_accept_rate"] = nn_accept_rate(alone.updates)
            assert {k: v for k, v in stored.items() if not timing(k) and k != "seed"} == expected, (name, seed)
            arrays = load_run_arrays(campaign / name / f"seed_{seed:05d}.npz")
            np.testing.assert_array_equal(arrays["x_d"], alone.x_d)
            np.testing.assert_array_equal(arrays["tau"], alone.tau)
    summary = json.loads((campaign / "summary.json").read_text())
    assert sorted(summary) == sorted(GOVERNORS) and all(s["runs"] == len(SEEDS) for s in summary.values())


def test_compare_a_learned_governor_against_the_conventional(campaign: Path, capsys) -> None:
    """`cikan compare --governor cikan --seeds 1-3`: ΔV ratio, success, violations and Verify calls
    per active update are those of the same runs as the campaign stored them (sums over the
    runs, computed here from the per-run files)."""
    from cikan_ros.montecarlo import load_run_arrays

    assert main(["compare", "--governor", "cikan", "--seeds", f"{SEEDS[0]}-{SEEDS[-1]}", "--json", *SHORT]) == 0
    (row,) = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.startswith("{")]
    mine, conv = runs_of(campaign, "cikan"), runs_of(campaign, "conventional")
    assert (row["variant"], row["governor"], row["runs"]) == ("default", "cikan", len(SEEDS))
    assert row["delta_v_ratio"] == pytest.approx(sum(m["delta_v_kmps"] for m in mine)
                                                 / sum(m["delta_v_kmps"] for m in conv), rel=1e-12)
    assert row["success"] == sum(m["success"] for m in mine)
    assert row["violations"] == sum(m["violations"] for m in mine)
    calls = active = 0
    for s in SEEDS:
        a = load_run_arrays(campaign / "cikan" / f"seed_{s:05d}.npz")
        searched = (a["update_tau_prev"] != 0.0) & ~np.isnan(a["update_tau_prev"])
        calls += int(a["update_verify_calls"][searched].sum())
        active += int(searched.sum())
    assert active > 0 and row["verify_calls_mean"] == pytest.approx(calls / active, rel=1e-12)
    assert row["active_speedup"] > 0


def test_report_tables_only(campaign: Path, tmp_path: Path) -> None:
    """`cikan report DIR --tables-only`: the page and Table 2 (Markdown, CSV), no figure; the CSV
    holds each governor's runs, dockings, violations, mean ΔV and ΔV against the conventional TSG
    as the per-run files give them."""
    assert main(["report", str(campaign), "--tables-only", "--out", str(tmp_path)]) == 0
    assert not list(tmp_path.glob("*.png"))
    page = (tmp_path / "report.md").read_text()
    assert ".png" not in page
    assert (tmp_path / "table2.md").read_text() in page
    with open(tmp_path / "table2.csv", newline="") as f:
        rows = {r["model"]: r for r in csv.DictReader(f)}
    assert sorted(rows) == sorted(GOVERNORS)
    dv = {g: np.mean([m["delta_v_kmps"] for m in runs_of(campaign, g)]) for g in GOVERNORS}
    for g in GOVERNORS:
        runs = runs_of(campaign, g)
        assert int(rows[g]["runs"]) == len(SEEDS)
        assert int(rows[g]["successes"]) == sum(m["success"] for m in runs)
        assert int(rows[g]["violations"]) == sum(m["violations"] for m in runs)
        assert int(rows[g]["violations_between"]) == sum(m["violations_between"] for m in runs)
        assert float(rows[g]["delta_v_kmps_mean"]) == pytest.approx(dv[g], rel=1e-12)
    assert float(rows["cikan"]["delta_v_vs_conventional"]) == pytest.approx(dv["cikan"] / dv["conventional"] - 1,
                                                                            abs=1e-12)


def test_report_scenarios_index(campaign: Path, tmp_path: Path) -> None:
    """`cikan report ROOT --scenarios`: README.md with one row per governor of each campaign under
    ROOT, naming its scenario and side; dockings, violations, mean ΔV and ΔV against the
    conventional TSG (mean, and the worst start) and the speed-up of whole missions (each start's
    active-update CPU, the conventional TSG's over the governor's: mean and worst) as the per-run
    files give them."""
    assert main(["report", str(campaign.parent), "--scenarios", "--out", str(tmp_path)]) == 0
    page = (tmp_path / "README.md").read_text()
    rows = {line.split(" | ")[3]: line for line in page.splitlines() if line.startswith("| paper | behind | nominal | ")}
    assert sorted(rows) == sorted(GOVERNORS)
    conv, mine = runs_of(campaign, "conventional"), runs_of(campaign, "cikan")
    for g, runs in (("conventional", conv), ("cikan", mine)):
        cells = rows[g].split(" | ")
        assert cells[4:9] == [str(len(SEEDS)), str(sum(m["success"] for m in runs)),
                              str(sum(m["violations"] for m in runs)),
                              str(sum(m["violations_between"] for m in runs)),
                              f"{np.mean([m['delta_v_kmps'] for m in runs]):.4f}"], rows[g]
    mean_ratio = np.mean([m["delta_v_kmps"] for m in mine]) / np.mean([m["delta_v_kmps"] for m in conv])
    worst = max(a["delta_v_kmps"] / b["delta_v_kmps"] for a, b in zip(mine, conv))
    assert rows["cikan"].split(" | ")[9] == f"{mean_ratio - 1:+.1%} ({worst - 1:+.0%})"
    assert rows["conventional"].split(" | ")[9] == "-"
    cpu = [[m["active_update_cpu_ms_mean"] * m["active_updates"] for m in runs] for runs in (conv, mine)]
    speedups = [c / g for c, g in zip(*cpu)]
    assert rows["cikan"].split(" | ")[11] == f"{np.mean(speedups):.2f} / {min(speedups):.2f}"


def test_train_like_a_shipped_model(cfg, predictor, tmp_path: Path, capsys) -> None:
    """`cikan train --model cikan --like cikan`: the new model has the shipped model's
    architecture and training hyper-parameters (its card, read here as JSON), trained on the
    given data, and its card says which model it was made like."""
    from cikan_ros.learn import dataset
    from cikan_ros.learn.dataset import DatasetSpec, generate, write_parquet

    dataset._PREDICTORS[json.dumps(cfg.flat(), sort_keys=True)] = predictor   # the session's gain table
    df, meta = generate(cfg, 120, DatasetSpec(seed=5, val_fraction=0.25, test_fraction=0.25), progress=False)
    data = write_parquet(df, meta, tmp_path / "labels.parquet")
    out = tmp_path / "like"
    assert main(["train", "--model", "cikan", "--like", "cikan", "--data", str(data), "--out", str(out),
                 "--epochs", "1", "--quiet", "--json", "--checkpoint-dir", str(tmp_path / "ck")]) == 0
    printed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    shipped = json.loads((MODELS_DIR / "cikan" / "card.json").read_text())
    card = json.loads((out / "card.json").read_text())
    assert card["architecture"] == shipped["architecture"] == printed["architecture"]
    for k in ("lr", "weight_decay", "batch", "theta_c"):
        assert card["training"][k] == shipped["training"][k], k
    assert card["training"]["lr_inf"] == pytest.approx(shipped["training"]["lr"] / 100, rel=1e-15)
    assert card["training"]["epochs"] == 1 and card["like"] == "cikan"
    assert card["dataset"]["labels"] == 120
    assert card["parameters"]["trainable"] == shipped["parameters"]["trainable"]


def test_models_page_is_the_committed_one(tmp_path: Path, capsys) -> None:
    """`cikan models --out FILE` (the command that writes models/README.md): the introduction of
    docs/models_intro.md, then the table of every model directory's card, row for row the table
    of the committed models/README.md; one row per card under models/."""
    page_path = tmp_path / "README.md"
    assert main(["models", "--out", str(page_path)]) == 0
    page = page_path.read_text()
    assert page.startswith((REPO / "docs" / "models_intro.md").read_text().rstrip())
    committed = (MODELS_DIR / "README.md").read_text()

    def card_rows(text: str) -> list[str]:
        section = text.split("## Models (from the cards)\n", 1)[1]
        return [line for line in section.split("\n## ", 1)[0].splitlines() if line.startswith("|")]
    assert card_rows(page) == card_rows(committed)
    cards = sorted(MODELS_DIR.rglob("card.json"))
    assert len(card_rows(page)) == 2 + len(cards)           # header, rule, one row per model
    for c in cards:
        assert any(f"| {c.parent.relative_to(MODELS_DIR)} |" in line for line in card_rows(page)), c
    # the Verify whose labels each model learned: robust for the F[-ahead]-robust directories
    for line in card_rows(page)[2:]:
        name, where = line.split(" | ")[0].strip("| "), line.split(" | ")[1]
        assert where.endswith(", robust" if name.endswith("-robust") else ", nominal"), line


def busy_loops() -> list[int]:
    """Pids of the live `--load` busy loops (children of this process)."""
    out = []
    for p in Path("/proc").iterdir():
        try:
            stat = (p / "stat").read_text().rsplit(")", 1)[1].split()
            cmd = (p / "cmdline").read_bytes()
        except (OSError, IndexError):
            continue
        if int(stat[1]) == os.getpid() and stat[0] != "Z" and b"while True: pass" in cmd:
            out.append(int(p.name))
    return out


def test_soak_under_load_fails_with_its_mission(ros_env: int, capsys: pytest.CaptureFixture) -> None:
    """`cikan soak --load` whose mission fails (a governor that gives up after 3 steps): it flies
    with every core busy, the table says which run failed and why, the busy loops end with the
    soak, and the command exits 1."""
    failing = f"{sys.executable} {Path(__file__).resolve().parent / 'failing_governor.py'} 3"
    code = main(["soak", "--load", "--runs", "1", "--json", "--set", "mission.duration_s=100",
                 "--governor-exec", failing])
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert code == 1, result
    assert (result["runs"], result["failed"], result["load"]) == (1, 1, True)
    (row,) = result["table"]
    assert not row["ok"] and "exited with code 3" in row["error"] and "giving up as planned" in row["error"]
    assert busy_loops() == []
