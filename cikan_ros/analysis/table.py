"""Table 2 of the paper from a Monte Carlo campaign directory (``cikan montecarlo --out DIR``).

Per governor: trainable parameters and the paper's complexity n^2 l (G+3) (from the model card),
train/val loss (card, the paper's definition), RMSE of tau against pi* solved at the states the
learned governor visited, update time mean / worst over all updates of all runs (the paper's
definition) and over active updates (tau_prev < 0), speed-up against the conventional TSG of the
same campaign, dV mean, success count, violations and the network acceptance rate. Update times
are CPU times of the deciding thread (``UpdateRecord.cpu_s``): wall times on a shared machine
also count waits for a core.
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..config import config_from_flat
from ..errors import CikanError
from ..governor import PATH_NN
from ..mission import errors_against_optimal, rmse, update_states
from ..montecarlo import load_run_arrays, summarise
from ..paired import paired_ratio
from ..registry import split_rule
from ..tsg import Predictor

#: The paper's Table 2 (SPEC §9): complexity, L_train, L_val (x1e-3), RMSE s, time mean/worst s, dV km/s.
PAPER = {
    "conventional": ("-", None, None, None, 0.0871, 0.8546, 3.8741),
    "cikan": ("1,638,400", 1.3218, 1.2615, 0.9652, 0.0329, 0.5590, 3.4965),
    "grbf": ("122,880", 1.4758, 1.1540, 0.8220, 0.0451, 1.0339, 3.5489),
    "rswaf": ("491,520", 1.5729, 1.2610, 1.2906, 0.0379, 0.5435, 3.4807),
    "relu": ("20,971,520", 2.7907, 1.6458, 0.7483, 0.0543, 1.3284, 3.6593),
    "gelu": ("5,242,880", 2.8983, 1.8538, 1.1202, 0.0299, 0.5292, 3.4549),
}
PAPER_NAMES = {"conventional": "TSG", "cikan": "CIKAN (128,5,17)", "grbf": "GRBF (32,6,17)",
               "rswaf": "RSWAF (64,6,17)", "relu": "CINN-ReLU (2048,5)", "gelu": "CINN-GELU (1024,5)"}

COLUMNS = ("model", "rule", "architecture", "trainable_params", "paper_complexity", "loss_train_1e3",
           "loss_val_1e3", "rmse_tau_s", "rmse_tau_active_s", "update_ms_mean", "update_ms_max",
           "active_update_ms_mean", "active_update_ms_max", "speedup_mean", "speedup_worst",
           "active_speedup_mean", "active_speedup_worst", "delta_v_kmps_mean", "delta_v_vs_conventional",
           "delta_v_vs_conventional_se",
           "t_tau_zero_s_mean", "t_tau_zero_vs_conventional", "successes", "runs", "violations",
           "violations_between", "nn_accept_rate", "mission_speedup_mean", "mission_speedup_worst")


def family_of(model: str) -> str:
    """Family of a shipped model directory name: ``cikan-prev`` -> ``cikan``."""
    return model.removesuffix("-prev")


def _runs(gov_dir: Path) -> list[tuple[dict[str, Any], dict[str, Any], Path]]:
    out = []
    for js in sorted(gov_dir.glob("seed_*.json")):
        npz = js.with_suffix(".npz")
        if npz.exists():
            stored = json.loads(js.read_text())
            if "refused" not in stored["metrics"]:  # (arrays left by an older run: not this one's)
                out.append((stored["metrics"], stored["config"], npz))
    return out


def rmse_against_optimal(runs: list[tuple[dict[str, Any], dict[str, Any], Path]]) -> tuple[float, float]:
    """(RMSE over all updates, RMSE over active updates) of a learned governor's shifts.

    pi* is the conventional TSG answer at the state the governor saw (through SI), from the same
    tau_prev (``mission.errors_against_optimal``; pi* = 0 with no prediction when tau_prev = 0).
    """
    pred: Predictor | None = None
    err_active: list[np.ndarray] = []
    err_zero: list[np.ndarray] = []
    for _, flat, npz in runs:
        cfg = config_from_flat(flat)
        if pred is None:
            pred = Predictor.from_config(cfg)
        a = load_run_arrays(npz)
        updates = list(zip(a["update_k"], a["update_tau_prev"], a["update_tau"]))
        states = update_states(cfg, a["t"], a["x_d"], a["x_c"], updates, active_only=False)
        err_active.append(errors_against_optimal(pred, states))
        err_zero.append(np.array([s.tau for s in states if not s.active]))
    e_active = np.concatenate(err_active) if err_active else np.empty(0)
    e_all = np.concatenate([e_active] + err_zero) if err_zero else e_active
    return rmse(e_all), rmse(e_active)


def pooled_accept_rate(runs: list[tuple[dict[str, Any], dict[str, Any], Path]]) -> float:
    """The network's acceptance over a campaign's runs: the share of all their active updates
    answered with the network's proposal (path "nn"), pooled (the definition of
    :func:`cikan_ros.learn.governor.nn_accept_rate`, read from each run's stored decisions); NaN
    without an active update."""
    active = accepted = 0
    for _, _, npz in runs:
        a = load_run_arrays(npz)
        is_active = (a["update_tau_prev"] != 0.0) & np.isfinite(a["update_tau_prev"])
        active += int(is_active.sum())
        accepted += int(np.sum(is_active & (a["update_path"] == PATH_NN)))
    return accepted / active if active else math.nan


def _card(name: str, flat: dict[str, Any] | None = None) -> dict[str, Any] | None:
    """The model card of governor ``name`` as the campaign (configuration ``flat``) flew it: a
    family resolves to its scenario's model for the approach side and Verify mode."""
    from ..learn.arch import FAMILIES
    from ..learn.modelfile import MODELS_DIR, flown_model_dir

    if name in FAMILIES and flat is not None:
        path = flown_model_dir(config_from_flat(flat), name)
    else:
        path = Path(name) if "/" in name else MODELS_DIR / name
    card = path / "card.json" if path.is_dir() else path.with_name("card.json")
    return json.loads(card.read_text()) if card.exists() else None


def campaign_scenario(mc_dir: str | Path) -> tuple[str, str]:
    """(scenario name, approach side) a Monte Carlo campaign flew (its first stored run)."""
    name, approach, _ = campaign_world(mc_dir)
    return name, approach


def verify_text(robust: bool, truth: str) -> str:
    """The Verify mode as the indexes name it: "nominal", or "robust (<truth>)"."""
    return f"robust ({truth})" if robust else "nominal"


def campaign_world(mc_dir: str | Path) -> tuple[str, str, str]:
    """(scenario name, approach side, Verify) a Monte Carlo campaign flew (its first stored run;
    Verify as :func:`verify_text` names it)."""
    for js in sorted(Path(mc_dir).glob("*/seed_*.json")):
        cfg = config_from_flat(json.loads(js.read_text())["config"])
        return cfg.scenario.name, cfg.mission.approach, verify_text(cfg.tsg.robust, cfg.truth.name)
    return "paper", "behind", "nominal"


def build_table(mc_dir: str | Path, with_rmse: bool = True) -> list[dict[str, Any]]:
    """Rows of Table 2 for every governor directory in a campaign (conventional first)."""
    mc = Path(mc_dir)

    def order(g: str) -> tuple:
        base, rule = split_rule(g)
        fam = family_of(base)
        return (g != "conventional", list(PAPER).index(fam) if fam in PAPER else 99, fam,
                base != fam, rule == "paper")

    govs = sorted((d.name for d in mc.iterdir() if d.is_dir() and any(d.glob("seed_*.json"))),
                  key=order)
    rows = []
    conv: dict[str, Any] | None = None
    conv_dv: dict[int, float] = {}
    conv_cpu: dict[int, float] = {}
    for g in govs:
        runs = _runs(mc / g)
        s = summarise([m for m, _, _ in runs])
        row: dict[str, Any] = {c: None for c in COLUMNS}
        base, rule = split_rule(g)
        if rule is None and g != "conventional":
            rule = config_from_flat(runs[0][1]).learned.algorithm if runs else None
        row.update(model=g, rule=rule, runs=s["runs"], successes=s["successes"],
                   violations=s["violations"], violations_between=s.get("violations_between"),
                   t_tau_zero_s_mean=s["t_tau_zero_s_mean"],
                   delta_v_kmps_mean=s["delta_v_kmps_mean"], update_ms_mean=s["update_cpu_ms_mean"],
                   update_ms_max=s["update_cpu_ms_max"], active_update_ms_mean=s["active_update_cpu_ms_mean"],
                   active_update_ms_max=s["active_update_cpu_ms_max"])
        if g == "conventional":
            conv = s
            conv_dv = {int(m["seed"]): m["delta_v_kmps"] for m, _, _ in runs}
            conv_cpu = {int(m["seed"]): active_cpu_ms(m) for m, _, _ in runs}
        else:
            paired = [(m["delta_v_kmps"], conv_dv[int(m["seed"])]) for m, _, _ in runs
                      if int(m["seed"]) in conv_dv]
            if len(paired) >= 2:
                row["delta_v_vs_conventional_se"] = paired_ratio(*zip(*paired)).se
            # whole missions: the conventional TSG's active CPU from the same start over this one's
            mine = ((conv_cpu.get(int(m["seed"]), 0.0), active_cpu_ms(m)) for m, _, _ in runs)
            ratios = [c / g for c, g in mine if c > 0 and g > 0]
            if ratios:
                row["mission_speedup_mean"] = float(np.mean(ratios))
                row["mission_speedup_worst"] = float(min(ratios))
            card = _card(base, runs[0][1] if runs else None)
            if card is not None:
                arch = card.get("architecture", {})
                row.update(architecture=_arch_label(arch),
                           trainable_params=card["parameters"]["trainable"],
                           paper_complexity=card["parameters"]["complexity_n2l_G3"],
                           loss_train_1e3=1e3 * card["losses"]["train"]["loss"],
                           loss_val_1e3=1e3 * card["losses"]["val"]["loss"])
            row["nn_accept_rate"] = pooled_accept_rate(runs)
            if with_rmse:
                row["rmse_tau_s"], row["rmse_tau_active_s"] = rmse_against_optimal(runs)
        rows.append(row)
    if conv is not None:
        for row in rows:
            if row["update_ms_mean"]:
                row["speedup_mean"] = conv["update_cpu_ms_mean"] / row["update_ms_mean"]
                row["speedup_worst"] = conv["update_cpu_ms_max"] / row["update_ms_max"]
            if row["active_update_ms_mean"]:
                row["active_speedup_mean"] = conv["active_update_cpu_ms_mean"] / row["active_update_ms_mean"]
                row["active_speedup_worst"] = conv["active_update_cpu_ms_max"] / row["active_update_ms_max"]
            row["delta_v_vs_conventional"] = row["delta_v_kmps_mean"] / conv["delta_v_kmps_mean"] - 1.0
            row["t_tau_zero_vs_conventional"] = row["t_tau_zero_s_mean"] / conv["t_tau_zero_s_mean"] - 1.0
    return rows


def active_cpu_ms(run: dict[str, Any]) -> float:
    """CPU time (ms) of a run's active updates (those with tau_prev != 0): the mission's cost."""
    n = run.get("active_updates") or 0
    return float(run["active_update_cpu_ms_mean"]) * n if n else 0.0


def _arch_label(arch: dict[str, Any]) -> str:
    w, d, g = arch.get("width"), arch.get("layers"), arch.get("grid")
    return f"({w},{d},{g})" if g and arch.get("family") not in ("relu", "gelu") else f"({w},{d})"


def _fmt(v: Any, spec: str) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return format(v, spec)


def to_markdown(rows: list[dict[str, Any]], paper_rows: bool = True) -> str:
    """Our Table 2 (the paper's all-updates timing, active-phase timing beside it), the paper's
    row under each family; learned rows name their update rule (keep: default, paper: the
    paper's Algorithm 1). ΔV and t(τ=0) also relative to the conventional TSG of the campaign,
    ΔV with the standard error of that paired ratio (``cikan_ros.paired``). ``paper_rows``
    False: without the paper's rows (another scenario or approach side)."""
    head = ("| model | rule | params (trainable) | complexity n²ℓ(G+3) | L_train, L_val ×1e-3 "
            "| RMSE τ (s) all / active | update ms mean / worst | speed-up mean / worst "
            "| active ms mean / worst | active speed-up mean / worst | ΔV (km/s) | t(τ=0) mean (s) "
            "| success | violations | between samples | NN accept |")
    lines = [head, "|" + "---|" * 16]

    def rel(v: Any, se: Any = None) -> str:
        if v is None or not math.isfinite(v):
            return ""
        return f" ({v:+.1%})" if se is None else f" ({100 * v:+.1f} ± {100 * se:.1f} %)"

    for i, r in enumerate(rows):
        g = r["model"]
        base, _ = split_rule(g)
        lines.append(
            f"| **{base}** {r['architecture'] or ''} | {r['rule'] or '-'} "
            f"| {_fmt(r['trainable_params'], ',')} | {_fmt(r['paper_complexity'], ',')} "
            f"| {_fmt(r['loss_train_1e3'], '.4f')}, {_fmt(r['loss_val_1e3'], '.4f')} "
            f"| {_fmt(r['rmse_tau_s'], '.4f')} / {_fmt(r['rmse_tau_active_s'], '.4f')} "
            f"| {_fmt(r['update_ms_mean'], '.3f')} / {_fmt(r['update_ms_max'], '.2f')} "
            f"| {_fmt(r['speedup_mean'], '.2f')} / {_fmt(r['speedup_worst'], '.2f')} "
            f"| {_fmt(r['active_update_ms_mean'], '.3f')} / {_fmt(r['active_update_ms_max'], '.2f')} "
            f"| {_fmt(r['active_speedup_mean'], '.2f')} / {_fmt(r['active_speedup_worst'], '.2f')} "
            f"| {_fmt(r['delta_v_kmps_mean'], '.4f')}{rel(r['delta_v_vs_conventional'], r['delta_v_vs_conventional_se']) if g != 'conventional' else ''} "
            f"| {_fmt(r['t_tau_zero_s_mean'], '.0f')}{rel(r['t_tau_zero_vs_conventional']) if g != 'conventional' else ''} "
            f"| {r['successes']}/{r['runs']} | {r['violations']} | {_fmt(r['violations_between'], 'd')} "
            f"| {_fmt(r['nn_accept_rate'], '.3f')} |")
        fam = family_of(base)
        last_of_family = i + 1 == len(rows) or family_of(split_rule(rows[i + 1]["model"])[0]) != fam
        if paper_rows and fam in PAPER and last_of_family:
            cx, lt, lv, rmse_p, tm, tw, dv = PAPER[fam]
            lines.append(
                f"| *paper: {PAPER_NAMES[fam]}* | {'-' if fam == 'conventional' else 'paper'} | - | {cx} "
                f"| {_fmt(lt, '.4f')}, {_fmt(lv, '.4f')} | {_fmt(rmse_p, '.4f')} "
                f"| {tm * 1e3:.1f} / {tw * 1e3:.0f} "
                f"| {_fmt(PAPER['conventional'][4] / tm, '.2f')} / {_fmt(PAPER['conventional'][5] / tw, '.2f')} "
                f"| - | - | {dv:.4f} | - | 100/100 | 0 | - | - |")
    return "\n".join(lines) + "\n"


def summary(rows: list[dict[str, Any]]) -> str:
    """What the table shows, per update rule, as ranges over the learned families (Markdown
    bullets, generated so that the prose around the table never restates a number by hand)."""
    def span(key: str, fmt: str, rs: list[dict[str, Any]]) -> str:
        v = [r[key] for r in rs if r[key] is not None and math.isfinite(r[key])]
        return "-" if not v else f"{format(min(v), fmt)} to {format(max(v), fmt)}"

    out = []
    learned = [r for r in rows if r["model"] != "conventional"]
    for rule in dict.fromkeys(r["rule"] for r in learned):
        rs = [r for r in learned if r["rule"] == rule]
        ok = sum(r["successes"] for r in rs)
        runs = sum(r["runs"] for r in rs)
        out.append(
            f"- **{rule} rule** ({', '.join(split_rule(r['model'])[0] for r in rs)}): "
            f"{ok}/{runs} runs docked, {sum(r['violations'] for r in rs)} violations; "
            f"active-phase speed-up {span('active_speedup_mean', '.2f', rs)}x mean and "
            f"{span('active_speedup_worst', '.2f', rs)}x worst; all-updates speed-up "
            f"{span('speedup_mean', '.2f', rs)}x mean and {span('speedup_worst', '.2f', rs)}x worst; "
            f"ΔV {span('delta_v_vs_conventional', '+.1%', rs)} (paired standard errors "
            f"{span('delta_v_vs_conventional_se', '.1%', rs)}) and mean time to τ = 0 "
            f"{span('t_tau_zero_vs_conventional', '+.1%', rs)} against the conventional TSG; "
            f"active-phase RMSE against π* {span('rmse_tau_active_s', '.3f', rs)} s.")
    return "\n".join(out) + "\n"


def to_csv(rows: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(COLUMNS))
    w.writeheader()
    for r in rows:
        w.writerow({c: r[c] for c in COLUMNS})
    return buf.getvalue()


def per_start_worst(mc_dir: str | Path, governor: str) -> tuple[float, float]:
    """(worst ΔV ratio, worst time-to-τ=0 ratio) of ``governor`` against the conventional TSG
    over the starts both flew in a campaign (NaN without a conventional run)."""
    def load(g: str) -> dict[int, dict[str, Any]]:
        return {int(m["seed"]): m for m, _, _ in _runs(Path(mc_dir) / g)}
    conv, gov = load("conventional"), load(governor)
    seeds = [s for s in gov if s in conv]
    if not seeds:
        return math.nan, math.nan
    dv = max(gov[s]["delta_v_kmps"] / conv[s]["delta_v_kmps"] for s in seeds)
    tt = [gov[s]["t_tau_zero_s"] / conv[s]["t_tau_zero_s"] for s in seeds
          if gov[s].get("t_tau_zero_s") and conv[s].get("t_tau_zero_s")]
    return dv, max(tt) if tt else math.nan


#: A campaign's rows of the scenario index, kept beside its page (``<pages>/<world>/``, e.g.
#: docs/results/scenarios/geo-behind/): a world whose runs are not on the machine is indexed
#: from there, so one world can be flown again without the others' runs.
INDEX_ROWS = "index_rows.md"
SCENARIOS_HEADER = ("| scenario | side | Verify | governor | runs | docked | violations | between samples "
                    "| ΔV mean (km/s) | ΔV vs conv. (worst start) | t(τ=0) vs conv. (worst start) "
                    "| mission speed-up mean / worst start | NN accept |")


def campaign_rows(mc_dir: str | Path) -> list[str]:
    """The scenario index's rows of one campaign (``make scenario-result``): each governor's
    docking, violations, ΔV and time to τ = 0 against the conventional TSG of the same campaign
    (mean ratio, and the worst start), and the speed-up of its whole missions (the conventional
    TSG's active-update CPU from the same start over its own: mean over the starts, and the
    worst)."""
    scenario, approach, verify = campaign_world(mc_dir)
    lines = []
    for r in build_table(mc_dir, with_rmse=False):
        g = r["model"]
        if g == "conventional":
            vs = tvs = "-"
            mission = "1.00 / 1.00"
        else:
            mission = f"{_fmt(r['mission_speedup_mean'], '.2f')} / {_fmt(r['mission_speedup_worst'], '.2f')}"
            wdv, wt = per_start_worst(mc_dir, g)
            vs = f"{r['delta_v_vs_conventional']:+.1%} ({wdv - 1:+.0%})"
            tvs = f"{r['t_tau_zero_vs_conventional']:+.1%} ({wt - 1:+.0%})"
        lines.append(
            f"| {scenario} | {approach} | {verify} | {g} | {r['runs']} | {r['successes']} | {r['violations']} "
            f"| {_fmt(r['violations_between'], 'd')} | {_fmt(r['delta_v_kmps_mean'], '.4f')} | {vs} | {tvs} "
            f"| {mission} | {_fmt(r['nn_accept_rate'], '.3f')} |")
    return lines


def scenarios_index(root: str | Path, pages: str | Path | None = None) -> str:
    """Markdown: one block of rows per campaign directory under ``root`` (``make
    scenario-results``: runs/scenario-results/<scenario>-<side>[-robust], the Verify mode read from
    the runs; :func:`campaign_rows`). With ``pages`` (the index's own directory, one
    subdirectory per world's page): each campaign's rows are also written to
    ``<pages>/<world>/index_rows.md``, and a world with a page but no campaign under ``root`` is
    indexed from its kept rows (its last flight), said under the table."""
    blocks: dict[str, list[str]] = {}
    for d in sorted(p for p in Path(root).iterdir() if p.is_dir()):
        blocks[d.name] = campaign_rows(d)
        if pages is not None:
            (Path(pages) / d.name).mkdir(parents=True, exist_ok=True)
            (Path(pages) / d.name / INDEX_ROWS).write_text("\n".join(blocks[d.name]) + "\n")
    kept = []
    if pages is not None and Path(pages).is_dir():
        for f in sorted(Path(pages).glob(f"*/{INDEX_ROWS}")):
            if f.parent.name not in blocks:
                blocks[f.parent.name] = [line for line in f.read_text().splitlines() if line.startswith("| ")]
                kept.append(f.parent.name)
    lines = [SCENARIOS_HEADER, "|" + "---|" * 13]
    for world in sorted(blocks):
        lines += blocks[world]
    text = "\n".join(lines) + "\n"
    if kept:
        text += (f"\nRows of {', '.join(kept)} as last flown (their runs are not under {root}; "
                 f"kept in each world's {INDEX_ROWS}).\n")
    return text


def bench_files(root: str | Path) -> list[tuple[Path, str, str, str, dict[str, Any]]]:
    """The ``cikan bench --json`` files under ``root`` named ``<scenario>-<side>[-robust].json``,
    sorted: (file, scenario, side, Verify as :func:`verify_text` names it, figures)."""
    files = sorted(Path(root).glob("*.json"))
    if not files:
        raise CikanError(f"no cikan bench JSON file in {root}")
    out = []
    for f in files:
        scenario, _, side = f.stem.removesuffix("-robust").rpartition("-")
        try:
            b = json.loads(f.read_text())
        except (OSError, ValueError) as exc:
            raise CikanError(f"cannot read bench file {f}: {exc}") from None
        out.append((f, scenario, side, verify_text(bool(b.get("robust")), b.get("truth", "nominal")), b))
    return out


def _refused_row(scenario: str, side: str, verify: str, why: str) -> str:
    """A ten-column row of the bench tables for a configuration whose Verify refused every start."""
    return f"| {scenario} | {side} | {verify} | - | every start refused: {why} | - | - | - | - | - |"


def bench_index(root: str | Path) -> str:
    """Markdown: the speed figures of each ``cikan bench --json`` output under ``root`` (``make
    scenario-bench``: ``<scenario>-<side>.json``, and ``<scenario>-<side>-robust.json`` under
    robust Verify; the Verify mode and truth are read from the file), one row per learned model.
    Whole missions as flown first (trust, audits and the stall rule included): the active-update
    speed-up against the conventional TSG's missions from the same starts (mean, and the worst
    single mission), Verify calls per active update (the conventional TSG's beside), the share
    of updates answered by searching and the network's acceptance; then, the network trusted,
    the per-update speed-up on the benchmark's states (mean / worst) and the conventional
    update's mean time. A model flown with ``learned.foreign_model`` (made for another scenario,
    side or Verify) is marked "(foreign)"."""
    from ..registry import LEARNED_NAMES

    lines = ["| scenario | side | Verify | model | mission speed-up mean / worst | Verify calls per active "
             "update (conventional) | searching | NN accept | per update, trusted: speed-up mean / worst "
             "| conventional update ms |", "|" + "---|" * 10]
    for f, scenario, side, verify, b in bench_files(root):
        if "refused" in b:   # cikan bench: Verify refused every start (timing.EveryStartRefusedError)
            lines.append(_refused_row(scenario, side, verify, b["refused"]))
            continue
        foreign = b.get("learned_foreign_models") or {}
        flown = [m for m in LEARNED_NAMES if f"{m}_speedup_mean" in b]
        if not flown:   # every model refused (none made for this Verify): said, with the conventional TSG's cost
            refused = ", ".join(m.split(":", 1)[0] for m in b.get("learned_models_missing") or []) or "none shipped"
            lines.append(f"| {scenario} | {side} | {verify} | - | no model flown (refused: {refused}) "
                         f"| - ({_fmt(b.get('conventional_verify_calls_mean'), '.2f')}) | - | - | - "
                         f"| {_fmt(b.get('conventional_update_ms_mean'), '.3f')} |")
        for m in flown:
            lines.append(
                f"| {scenario} | {side} | {verify} | {m}{' (foreign)' if m in foreign else ''} "
                f"| {_fmt(b.get(f'{m}_mission_speedup_mean'), '.2f')} / {_fmt(b.get(f'{m}_mission_speedup_worst'), '.2f')} "
                f"| {_fmt(b.get(f'{m}_mission_verify_calls_mean'), '.2f')} "
                f"({_fmt(b.get('mission_conventional_verify_calls_mean'), '.2f')}) "
                f"| {_fmt(b.get(f'{m}_search_rate'), '.1%')} | {_fmt(b.get(f'{m}_mission_nn_accept_rate'), '.1%')} "
                f"| {_fmt(b[f'{m}_speedup_mean'], '.2f')} / {_fmt(b.get(f'{m}_speedup_worst'), '.2f')} "
                f"| {_fmt(b.get('learned_conventional_update_ms_mean'), '.3f')} |")
    return "\n".join(lines) + "\n"


def ceiling_index(root: str | Path) -> str:
    """Markdown: the ceiling of each ``cikan bench --section conventional --json`` file under ``root``
    (``make scenario-ceiling``: ``<scenario>-<side>[-robust].json``), one row per scenario, side
    and Verify mode: the conventional TSG's active update (CPU ms, Verify calls) against an
    oracle that knows pi* and verifies it once (its CPU per state, the share of states where
    pi* = tau_prev and it holds for free), and the oracle's speed-up of whole missions (mean over
    the benchmark's missions, the worst, and all states pooled): what any governor that tracks
    pi* and verifies what it flies can reach at most (``cikan_ros.bench.ceiling_figures``)."""
    lines = ["| scenario | side | Verify | missions | active states | conventional update ms (Verify calls) "
             "| oracle update ms | π* = τ_prev | oracle mission speed-up mean / worst | all states |",
             "|" + "---|" * 10]
    for f, scenario, side, verify, b in bench_files(root):
        if "refused" in b:
            lines.append(_refused_row(scenario, side, verify, b["refused"]))
            continue
        if "oracle_mission_speedup_mean" not in b:
            raise CikanError(f"{f} has no ceiling (oracle_*): made by a cikan bench before it")
        refused = b.get("n_missions_infeasible", 0)   # n_missions counts the missions flown
        missions = f"{b['n_missions']}" + (f" (+{refused} refused)" if refused else "")
        lines.append(
            f"| {scenario} | {side} | {verify} | {missions} | {b['n_update_states']} "
            f"| {_fmt(b['conventional_update_ms_mean'], '.3f')} ({_fmt(b['conventional_verify_calls_mean'], '.1f')}) "
            f"| {_fmt(b['oracle_update_ms_mean'], '.3f')} | {_fmt(b['oracle_hold_rate'], '.0%')} "
            f"| {_fmt(b['oracle_mission_speedup_mean'], '.2f')} / {_fmt(b['oracle_mission_speedup_worst'], '.2f')} "
            f"| {_fmt(b['oracle_cpu_speedup'], '.2f')} |")
    return "\n".join(lines) + "\n"
