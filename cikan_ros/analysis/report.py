"""``cikan report``: the paper's figures and a Markdown page from recorded runs.

Sources: one rosbag2 bag directory, a directory of bags, or a Monte Carlo campaign directory
(``cikan montecarlo --out``; per-run ``.npz`` results). Bags are read with rosbags (an independent
reader) and rebuilt into the same run record the offline mission produces, so the metrics on the
page are computed by the same code as in-process.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ..config import Config
from ..errors import CikanError
from ..montecarlo import load_run_arrays, summarise
from .figures import RunData, all_figures, constraint_histories, mean_tau

#: Runs per governor drawn in the trajectory figures of a campaign (all runs enter Fig. 3c).
MAX_DRAWN = 12

METRIC_ROWS = (("success", "{}"), ("violations", "{}"), ("tau0_s", "{:.4f}"), ("t_tau_zero_s", "{}"),
               ("t_docked_s", "{}"), ("final_distance_m", "{:.3e}"), ("final_speed_mps", "{:.3e}"),
               ("delta_v_kmps", "{:.4f}"), ("min_h1_margin", "{:.3e}"), ("max_h3", "{:.3e}"),
               ("updates", "{}"), ("update_ms_mean", "{:.3f}"), ("update_ms_max", "{:.3f}"),
               ("active_update_ms_mean", "{:.3f}"), ("active_update_ms_max", "{:.3f}"),
               ("unverified_shifts", "{}"), ("off_schedule_shifts", "{}"), ("missing_shifts", "{}"))


def is_bag(path: Path) -> bool:
    return (path / "metadata.yaml").exists()


def run_from_bag(path: Path, cfg: Config | None = None) -> tuple[RunData, dict[str, Any]]:
    """A bag's run history and its metrics (computed by MissionResult.metrics)."""
    from ..ros.bag_reader import bag_config, bag_governor, recorded_metrics

    config = bag_config(path, cfg)
    gov = bag_governor(path)
    res, metrics = recorded_metrics(path, config, gov)
    m = res.margins
    return (RunData(gov, res.t, res.x_d, res.x_c, res.u, res.tau, m.h1_normalised, m.h2, m.h3,
                    label=path.name), metrics)


def run_from_npz(json_path: Path) -> tuple[RunData, dict[str, Any]]:
    """A Monte Carlo run's history and stored metrics."""
    stored = json.loads(json_path.read_text())
    a = load_run_arrays(json_path.with_suffix(".npz"))
    gov = json_path.parent.name
    return (RunData(gov, a["t"], a["x_d"], a["x_c"], a["u"], a["tau"], a["h1_normalised"], a["h2"], a["h3"],
                    label=f"{gov} seed {stored['metrics'].get('seed')}"), stored["metrics"])


def load_runs(path: str | Path, cfg: Config | None = None) -> tuple[str, list[RunData], list[dict[str, Any]]]:
    """(kind, runs, metrics) of a bag, a directory of bags, or a Monte Carlo directory."""
    p = Path(path)
    if not p.exists():
        raise CikanError(f"no such bag or directory: {p}")
    if is_bag(p):
        run, metrics = run_from_bag(p, cfg)
        return "bag", [run], [metrics]
    bags = sorted(d for d in p.iterdir() if d.is_dir() and is_bag(d))
    if bags:
        loaded = [run_from_bag(b, cfg) for b in bags]
        return "bags", [r for r, _ in loaded], [m for _, m in loaded]
    order = ["conventional", "cikan", "grbf", "rswaf", "relu", "gelu"]
    jsons = sorted(p.glob("*/seed_*.json"), key=lambda j: (
        order.index(j.parent.name) if j.parent.name in order else len(order), j.parent.name, j.name))
    if jsons:
        loaded = [run_from_npz(j) for j in jsons]
        return "montecarlo", [r for r, _ in loaded], [m for _, m in loaded]
    raise CikanError(f"{p} holds no rosbag2 bag (metadata.yaml) and no Monte Carlo results (*/seed_*.json)")


def _metrics_table(runs: list[RunData], metrics: list[dict[str, Any]]) -> str:
    head = "| metric | " + " | ".join(r.label or r.governor for r in runs) + " |"
    lines = [head, "|---|" + "---|" * len(runs)]
    for key, fmt in METRIC_ROWS:
        cells = []
        for m in metrics:
            v = m.get(key)
            cells.append("-" if v is None else fmt.format(v))
        lines.append(f"| {key} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_report(path: str | Path, out_dir: str | Path, cfg: Config | None = None,
                 title: str | None = None, notes: str | None = None, figures: bool = True) -> Path:
    """Figures (PNG) and ``report.md`` for the runs at ``path``; returns the page's path.

    ``notes`` (Markdown) is inserted after the tables, before the figures; ``figures`` False
    writes the tables only. The paper's Table 2 rows appear beside a campaign of the paper's
    scenario from behind only.
    """
    from .table import build_table, campaign_scenario, summary, to_csv, to_markdown

    kind, runs, metrics = load_runs(path, cfg)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    lines = [f"# {title or 'cikan_ros run report'}", "",
             f"Source: `{Path(path).name}` ({kind}, {len(runs)} run{'s' if len(runs) != 1 else ''}).", ""]
    if kind == "montecarlo":
        govs = list(dict.fromkeys(r.governor for r in runs))
        drawn = [r for g in govs for r in [x for x in runs if x.governor == g][:MAX_DRAWN]]
        worst = min(range(len(runs)), key=lambda i: metrics[i].get("min_h1_margin") or 0.0)
        figs = all_figures(drawn, out) if figures else {}
        if figures:
            figs["fig3c_mean_tau"] = mean_tau(runs, out / "fig3c_mean_tau.png")
            # Fig. 4: the run closest to the LoS boundary (the paper shows an extreme case).
            figs["fig4_constraints"] = constraint_histories([runs[worst]], out / "fig4_constraints.png")
        rows = build_table(path)
        scenario, approach = campaign_scenario(path)
        table = to_markdown(rows, paper_rows=(scenario, approach) == ("paper", "behind"))
        (out / "table2.md").write_text(table)
        (out / "table2.csv").write_text(to_csv(rows))
        lines += [f"Scenario `{scenario}`, approach from {approach}.", "",
                  "## Table 2", "", table, "", "What it shows (generated from the table):", "",
                  summary(rows), "",
                  f"Per governor over its runs (the trajectory figures draw the first {MAX_DRAWN} runs of each; "
                  f"Fig. 4 shows run `{runs[worst].label}`, the one closest to the LoS boundary).", ""]
        lines += ["| governor | runs | successes | violations | ΔV mean (km/s) | min h1 margin |", "|---|---|---|---|---|---|"]
        for g in govs:
            s = summarise([m for r, m in zip(runs, metrics) if r.governor == g])
            lines.append(f"| {g} | {s['runs']} | {s['successes']} | {s['violations']} | "
                         f"{s['delta_v_kmps_mean']:.4f} | {s['min_h1_margin']:.2e} |")
        lines.append("")
    else:
        figs = all_figures(runs, out) if figures else {}
        lines += ["## Metrics", "", _metrics_table(runs, metrics), ""]
    if notes:
        lines += [notes.rstrip(), ""]
    (out / "metrics.json").write_text(json.dumps(metrics, indent=1))
    captions = {
        "fig3a_relative_vnb": "Fig. 3a: relative trajectories in the chief's VNB frame with the LoS cone",
        "fig3a_relative_vnb_zoom": "Fig. 3a (zoom): the last 5 km",
        "fig3b_tau": "Fig. 3b: time shift histories",
        "fig3c_mean_tau": "Fig. 3c: mean time shift",
        "fig3d_distance": "Fig. 3d: relative distance",
        "fig3e_speed": "Fig. 3e: relative speed",
        "fig4_constraints": "Fig. 4: constraint histories h1, h2, h3",
    }
    lines += ["## Figures", ""] if figs else []
    for name, fpath in figs.items():
        lines += [f"### {captions.get(name, name)}", "", f"![{name}]({Path(fpath).name})", ""]
    page = out / "report.md"
    page.write_text("\n".join(lines))
    return page
