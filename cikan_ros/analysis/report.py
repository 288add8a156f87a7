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

from ..config import Config, config_from_flat
from ..errors import CikanError
from ..montecarlo import load_run_arrays, markdown_summary, summarise
from ..strict_json import dumps
from .figures import RunData, all_figures, constraint_histories, mean_tau
from .flown import flown_markdown, flown_rows, governors_text, metric_rows

#: Runs per governor drawn in the trajectory figures of a campaign (all runs enter Fig. 3c).
MAX_DRAWN = 12

def is_bag(path: Path) -> bool:
    return (path / "metadata.yaml").exists()


def run_from_bag(path: Path, cfg: Config | None = None) -> tuple[RunData, dict[str, Any]]:
    """A bag's run history and its metrics (computed by MissionResult.metrics); of a damaged bag,
    what is readable of it, with ``partial``: what is missing
    (:func:`cikan_ros.ros.bag_reader.read_bag_partial`)."""
    from ..ros.bag_reader import bag_config, bag_governor, bag_model, read_bag_partial, recorded_metrics

    config = bag_config(path, cfg)
    gov = bag_governor(path)
    msgs, missing = read_bag_partial(path)
    res, metrics = recorded_metrics(path, config, gov, msgs)
    if missing:
        metrics["partial"] = missing
    m = res.margins
    return (RunData(gov, res.t, res.x_d, res.x_c, res.u, res.tau, m.h1_normalised, m.h2, m.h3, config,
                    label=path.name, model=bag_model(path)), metrics)


def run_from_npz(json_path: Path) -> tuple[RunData, dict[str, Any]]:
    """A Monte Carlo run's history and stored metrics."""
    stored = json.loads(json_path.read_text())
    a = load_run_arrays(json_path.with_suffix(".npz"))
    gov = json_path.parent.name
    return (RunData(gov, a["t"], a["x_d"], a["x_c"], a["u"], a["tau"], a["h1_normalised"], a["h2"], a["h3"],
                    config_from_flat(stored["config"]), label=f"{gov} seed {stored['metrics'].get('seed')}"),
            stored["metrics"])


def source_dir(path: str | Path) -> Path:
    """The directory a report reads: ``path``, or the bag a bag's .mcap file belongs to;
    CikanError (one line) for anything else."""
    p = Path(path)
    if not p.exists():
        raise CikanError(f"no such bag or directory: {p}")
    if p.is_file() and p.suffix == ".mcap" and is_bag(p.parent):
        return p.parent   # the bag's data file: the bag is its directory
    if not p.is_dir():
        raise CikanError(f"{p} is a file: give a bag directory (with metadata.yaml), a directory of bags "
                         "or a Monte Carlo directory")
    return p


def load_runs(path: str | Path, cfg: Config | None = None) -> tuple[str, list[RunData], list[dict[str, Any]]]:
    """(kind, runs, metrics) of a bag, a directory of bags, or a Monte Carlo directory."""
    p = source_dir(path)
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
        # A start Verify refused (robust Verify) was not flown: its JSON says why and has no npz.
        loaded = [run_from_npz(j) for j in jsons if j.with_suffix(".npz").exists()]
        if not loaded:
            raise CikanError(f"{p}: Verify refused every start of the campaign ({len(jsons)}); nothing flew")
        return "montecarlo", [r for r, _ in loaded], [m for _, m in loaded]
    raise CikanError(f"{p} holds no rosbag2 bag (metadata.yaml) and no Monte Carlo results (*/seed_*.json)")


def refused_starts(mc_dir: str | Path) -> dict[str, int]:
    """``{governor: starts refused}`` of a Monte Carlo directory (runs stored with ``refused``
    and no trajectory), for the governors that had any."""
    out: dict[str, int] = {}
    for j in sorted(Path(mc_dir).glob("*/seed_*.json")):
        if not j.with_suffix(".npz").exists() and "refused" in json.loads(j.read_text()).get("metrics", {}):
            out[j.parent.name] = out.get(j.parent.name, 0) + 1
    return out


def _metrics_table(runs: list[RunData], metrics: list[dict[str, Any]]) -> str:
    """What each run flew and its metrics, one column per run (labels of the first run)."""
    columns = [flown_rows(r.config, m["governor"], r.model, m.get("nn_accept_rate")) + metric_rows(m, r.config)
               for r, m in zip(runs, metrics)]
    lines = ["| | " + " | ".join(r.label or r.governor for r in runs) + " |", "|---|" + "---|" * len(runs)]
    for i, (label, _) in enumerate(columns[0]):
        lines.append(f"| {label} | " + " | ".join(col[i][1] if i < len(col) else "-" for col in columns) + " |")
    return "\n".join(lines) + "\n"


def write_report(path: str | Path, out_dir: str | Path, cfg: Config | None = None,
                 title: str | None = None, notes: str | None = None, figures: bool = True) -> Path:
    """Figures (PNG) and ``report.md`` for the runs at ``path``; returns the page's path.

    ``notes`` (Markdown) is inserted after the tables, before the figures; ``figures`` False
    writes the tables only. The paper's Table 2 rows appear beside a campaign of the paper's
    scenario from behind only.
    """
    from .table import build_table, summary, to_csv, to_markdown

    path = source_dir(path)
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
        cfg_flown = runs[0].config
        table = to_markdown(rows, paper_rows=(cfg_flown.scenario.name, cfg_flown.mission.approach) == ("paper", "behind"))
        (out / "table2.md").write_text(table)
        (out / "table2.csv").write_text(to_csv(rows))
        refused = refused_starts(path)
        first = sorted(refused, key=lambda g: (govs.index(g) if g in govs else len(govs), g))
        said = ("Starts Verify refused (no feasible shift at the first instant: not flown, not in the "
                "table): " + ", ".join(f"{g} {refused[g]} of {refused[g] + sum(r.governor == g for r in runs)}"
                                       for g in first) + ".\n\n") if refused else ""
        lines += [flown_markdown(flown_rows(cfg_flown, governors_text(govs, cfg_flown))),
                  "## Table 2", "", table, "", said + "What it shows (generated from the table):", "",
                  summary(rows), "",
                  f"Per governor over its runs (the trajectory figures draw the first {MAX_DRAWN} runs of each; "
                  f"Fig. 4 shows run `{runs[worst].label}`, the one closest to the LoS boundary).", ""]
        lines += [markdown_summary({g: summarise([m for r, m in zip(runs, metrics) if r.governor == g])
                                    for g in govs})]
    else:
        figs = all_figures(runs, out) if figures else {}
        lines += [f"**Partial report** of `{r.label}`: {m['partial']}.\n" for r, m in zip(runs, metrics)
                  if m.get("partial")]
        lines += ["## Metrics", "", _metrics_table(runs, metrics), ""]
    if notes:
        lines += [notes.rstrip(), ""]
    (out / "metrics.json").write_text(dumps(metrics, indent=1))
    captions = {
        "fig3a_relative_vnb": "Fig. 3a: relative trajectories in the chief's VNB frame with the LoS cone",
        "fig3a_relative_vnb_zoom": f"Fig. 3a (zoom): the last {runs[0].config.constraints.gamma1_km:g} km "
                                   "(where h3 applies)",
        "fig3b_tau": "Fig. 3b: time shift histories",
        "fig3c_mean_tau": "Fig. 3c: mean time shift",
        "fig3d_distance": "Fig. 3d: relative distance",
        "fig3e_speed": "Fig. 3e: relative speed",
        "fig4_constraints": "Fig. 4: constraint histories h1, h2 (m/s²), h3 (m/s)",
    }
    lines += ["## Figures", ""] if figs else []
    for name, fpath in figs.items():
        lines += [f"### {captions.get(name, name)}", "", f"![{name}]({Path(fpath).name})", ""]
    page = out / "report.md"
    page.write_text("\n".join(lines))
    return page
