"""A Markdown table of the shipped models from their cards: ``python -m cikan_ros.learn.cards``."""

from __future__ import annotations

from ..governor import LEARNED_NAMES
from .errors import ModelFileError
from .modelfile import load_model

PAPER_VAL = {"cikan": 1.2615e-3, "grbf": 1.1540e-3, "rswaf": 1.2610e-3, "relu": 1.6458e-3,
             "gelu": 1.8538e-3}


def table() -> str:
    rows = ["| model | (n, l, G) | params | n²l(G+3) | θ_c | L_train | L_val | L_test | L_val (θ_c=1) | L_val paper "
            "| RMSE τ test (s) | epochs | CPU wall (s) | TPE trials (complete/pruned) |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in LEARNED_NAMES:
        try:
            m = load_model(name)
        except ModelFileError as exc:
            rows.append(f"| {name} | missing: {exc} |")
            continue
        a, c = m.arch, m.card
        L, tr, tun = c["losses"], c["training"], c.get("tuning", {})
        size = f"({a.width}, {a.layers}, {a.grid})" if a.is_kan else f"({a.width}, {a.layers}, -)"
        rows.append(
            f"| {name} | {size} | {a.n_params():,} | {a.complexity():,} | {L['theta_c']:.2f} "
            f"| {L['train']['loss']:.3e} | {L['val']['loss']:.3e} | {L['test']['loss']:.3e} "
            f"| {L['val']['loss_theta1']:.3e} | {PAPER_VAL[name]:.3e} | {L['test']['rmse_tau_s']:.3f} | {tr['epochs_run']}/{tr['epochs']} "
            f"| {tr['cpu_budget']['wall_s']:.0f} | {tun.get('trials', 0)} "
            f"({tun.get('complete', 0)}/{tun.get('pruned', 0)}) |")
    return "\n".join(rows)


if __name__ == "__main__":
    print(table())
