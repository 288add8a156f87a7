"""Training (SPEC §7): AdamW, ExpHyperbolicLR per epoch, the constraint-informed log loss,
checkpoints (safetensors + JSON, no pickle) with resume, early stopping, a wall-clock budget.

Losses are reported in the paper's definition: L = mean((y - ŷ)²) + θ_c mean(ReLU(y - ŷ)²) with
y = ln|τ*| over the whole split, at the training θ_c, and also at θ_c = 1 for comparison.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch
from numpy.typing import NDArray

from .arch import Arch
from .dataset import SPLITS, XC_COLS, XD_COLS, read_parquet
from .errors import DatasetError, ModelFileError
from .features import features, fit_normalisation
from .loss import cinn_log_loss, cinn_log_loss_np
from .modelfile import card_scenario, label_config, library_versions, save_model
from .models import TimeShiftNet
from .schedule import ExpHyperbolicLR


@dataclass
class SplitData:
    """Raw float64 features (n, I), targets y (n,), τ* (n,), mission ids and the offset (n,)
    with ln|τ*| = y + offset: y = ln|τ*| and offset 0 for a ``log-shift`` network, y =
    ln(|τ*| / |τ_{k-1}|) and offset ln|τ_{k-1}| for a ``log-ratio`` one (``cikan_ros.learn.arch``)."""

    feats: NDArray
    y: NDArray
    tau: NDArray
    mission: NDArray
    offset: NDArray

    def head(self, n: int) -> "SplitData":
        """The first n labels."""
        return SplitData(self.feats[:n], self.y[:n], self.tau[:n], self.mission[:n], self.offset[:n])


@dataclass
class Data:
    splits: dict[str, SplitData]
    meta: dict[str, Any]
    path: str
    features: str = "vnb"
    target: str = "log-shift"


def load_data(path: str | Path | Sequence[str | Path], kind: str = "vnb", target: str = "log-shift") -> Data:
    """Read a dataset, or several concatenated (each label keeps its own file's split), and
    compute features (float64) and targets (``target``, :data:`~cikan_ros.learn.arch.TARGETS`)
    per split. Several files: e.g. conventional labels plus on-policy labels of a learned
    governor (``cikan dataset --governor``)."""
    from .arch import log_shift_offset, target_problem

    problem = target_problem(kind, target)
    if problem:
        raise ModelFileError(f"feature set {kind!r}: {problem}")
    import pandas as pd

    paths = [path] if isinstance(path, (str, Path)) else list(path)
    if not paths:
        raise DatasetError("no dataset given")
    frames, metas = zip(*(read_parquet(p) for p in paths))
    sides = set()
    for p, df in zip(paths, frames):
        tau = df["tau_star_s"]
        if (tau == 0).any() or not ((tau < 0).all() or (tau > 0).all()):
            raise DatasetError(f"dataset {p} has labels tau* = 0 or of both signs (one approach "
                               f"side per dataset, tau* != 0)")
        sides.add(bool(len(tau) and tau.iloc[0] > 0))
    if len(sides) > 1:
        raise DatasetError("datasets of both approach sides (tau* < 0 and tau* > 0) cannot be mixed")
    df = frames[0] if len(frames) == 1 else pd.concat(frames, ignore_index=True)
    meta = dict(metas[0])
    if len(paths) > 1:
        meta.update(labels=int(len(df)), split_labels={s: int((df["split"] == s).sum()) for s in SPLITS},
                    files=[{"file": Path(p).name, "governor": m.get("governor", "conventional"),
                            "labels": m.get("labels"), "seed": m.get("seed")} for p, m in zip(paths, metas)])
    path = "+".join(Path(p).name for p in paths) if len(paths) > 1 else paths[0]
    out = {}
    for s in SPLITS:
        part = df[df["split"] == s]
        feats = features(part[list(XD_COLS)].to_numpy(), part[list(XC_COLS)].to_numpy(), kind,
                         part["tau_prev_s"].to_numpy(dtype=np.float64))
        tau = part["tau_star_s"].to_numpy(dtype=np.float64)
        offset = log_shift_offset(target, feats)
        out[s] = SplitData(feats, np.log(np.abs(tau)) - offset, tau, part["mission"].to_numpy(), offset)
    if len(out["train"].y) == 0 or len(out["val"].y) == 0:
        raise DatasetError(f"dataset {path} needs non-empty train and val splits "
                           f"(has {[len(out[s].y) for s in SPLITS]})")
    return Data(out, meta, str(path), kind, target)


@dataclass
class TrainConfig:
    """Training hyper-parameters (epochs are ExpHyperbolicLR's N; U = upper_bound, 0 means N)."""

    epochs: int = 40
    upper_bound: int = 0
    lr: float = 3e-3
    lr_inf: float = 3e-5
    weight_decay: float = 1e-5
    batch: int = 512
    theta_c: float = 1.0
    patience: int = 8
    seed: int = 0
    max_minutes: float = 0.0      # wall budget; 0 = none
    threads: int = 1
    max_train: int = 0            # use only the first n training labels (0 = all)
    extra: dict[str, Any] = field(default_factory=dict)

    def check(self) -> None:
        if self.epochs < 0 or self.batch < 1 or self.patience < 1 or self.threads < 1:
            raise DatasetError("epochs must be >= 0 (0: the untrained network, random initial "
                               "weights), batch, patience and threads >= 1")
        if not (self.lr > 0 and self.lr_inf > 0 and self.weight_decay >= 0 and self.theta_c >= 0):
            raise DatasetError("need lr > 0, lr_inf > 0, weight_decay >= 0, theta_c >= 0")
        if self.upper_bound and self.upper_bound < self.epochs:
            raise DatasetError("upper_bound U must be >= epochs N")


def _tensor(a: NDArray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))


@torch.inference_mode()
def predict(net: TimeShiftNet, z: torch.Tensor, batch: int = 8192) -> NDArray:
    """Target predictions (float64; ln|τ| for a log-shift network) for z-scored features z (n, I)."""
    net.eval()
    out = [net(z[i:i + batch]).double() for i in range(0, len(z), batch)]
    return torch.cat(out).numpy() if out else np.empty(0)


def split_report(net: TimeShiftNet, z: torch.Tensor, s: SplitData, theta_c: float) -> dict[str, float]:
    """Loss (paper's definition at θ_c and at 1), its parts, and RMSE of τ (s) on a split."""
    if len(s.y) == 0:
        return {}
    p = predict(net, z)
    err = s.y - p
    tau_hat = np.sign(s.tau) * np.exp(p + s.offset)
    return {
        "loss": cinn_log_loss_np(p, s.y, theta_c),
        "loss_theta1": cinn_log_loss_np(p, s.y, 1.0),
        "mse_log": float(np.mean(err * err)),
        "relu2_log": float(np.mean(np.maximum(err, 0.0) ** 2)),
        "rmse_tau_s": float(np.sqrt(np.mean((tau_hat - s.tau) ** 2))),
        "under_fraction": float(np.mean(p < s.y)),   # predicted |τ| smaller than the label
        "labels": int(len(s.y)),
    }


# -- checkpoints (safetensors + JSON; no pickle) ---------------------------------------------------
def _save_checkpoint(d: Path, net: TimeShiftNet, opt: torch.optim.Optimizer, best: dict[str, torch.Tensor],
                     state: dict[str, Any]) -> None:
    from safetensors.torch import save_file

    d.mkdir(parents=True, exist_ok=True)
    tensors = {f"model.{k}": v.detach().clone() for k, v in net.state_dict().items()}
    tensors.update({f"best.{k}": v.detach().clone() for k, v in best.items()})
    osd = opt.state_dict()
    for i, st in osd["state"].items():
        for k, v in st.items():
            tensors[f"opt.{i}.{k}"] = v.detach().clone() if torch.is_tensor(v) else torch.tensor(float(v))
    save_file(tensors, str(d / "checkpoint.safetensors.tmp"))
    (d / "checkpoint.safetensors.tmp").replace(d / "checkpoint.safetensors")
    meta = {**state, "param_groups": osd["param_groups"]}
    (d / "checkpoint.json.tmp").write_text(json.dumps(meta))
    (d / "checkpoint.json.tmp").replace(d / "checkpoint.json")


def _load_checkpoint(d: Path, net: TimeShiftNet, opt: torch.optim.Optimizer
                     ) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    try:
        tensors = load_file(str(d / "checkpoint.safetensors"))
        meta = json.loads((d / "checkpoint.json").read_text())
    except (OSError, SafetensorError, json.JSONDecodeError) as exc:
        raise ModelFileError(f"cannot resume from {d}: {exc}") from None
    net.load_state_dict({k[6:]: v for k, v in tensors.items() if k.startswith("model.")})
    best = {k[5:]: v for k, v in tensors.items() if k.startswith("best.")}
    state: dict[int, dict[str, torch.Tensor]] = {}
    for k, v in tensors.items():
        if k.startswith("opt."):
            _, i, name = k.split(".", 2)
            state.setdefault(int(i), {})[name] = v
    opt.load_state_dict({"state": state, "param_groups": meta.pop("param_groups")})
    return best, meta


def train(arch: Arch, data: Data, cfg: TrainConfig, out: str | Path | None,
          checkpoint_dir: str | Path | None = None, resume: bool = False, progress: bool = False,
          on_epoch: Callable[[int, float], None] | None = None, name: str | None = None,
          card_extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """Train one network; write the best (lowest validation loss) to ``out`` as a model file.

    ``on_epoch(epoch, val_loss_at_theta_c_1)`` is called after every epoch (Optuna pruning raises
    from it; θ_c = 1 makes losses of trials with different θ_c comparable).
    ``progress``: show a progress bar (:mod:`cikan_ros.progress`).
    Returns the card's ``losses`` and ``training`` sections.
    """
    from ..progress import Bar

    cfg.check()
    if arch.features != data.features:
        raise DatasetError(f"architecture uses feature set {arch.features!r}, data has {data.features!r}")
    if arch.target != data.target:
        raise DatasetError(f"architecture learns target {arch.target!r}, data has {data.target!r}")
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    tr = data.splits["train"]
    n_train = len(tr.y) if cfg.max_train <= 0 else min(cfg.max_train, len(tr.y))
    mean, std = fit_normalisation(tr.feats[:n_train])
    y_mean, y_std = float(tr.y[:n_train].mean()), float(tr.y[:n_train].std() or 1.0)
    net = TimeShiftNet(arch)
    net.set_normalisation(mean, std, y_mean, y_std)
    z = {s: _tensor((data.splits[s].feats - mean) / std) for s in SPLITS}
    yt = _tensor(tr.y[:n_train])
    z_train = z["train"][:n_train]
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = ExpHyperbolicLR(opt, max(cfg.epochs, 1), cfg.upper_bound or max(cfg.epochs, 1), cfg.lr_inf)
    ckpt = Path(checkpoint_dir) if checkpoint_dir else None
    st: dict[str, Any] = {"epoch": 0, "best_val": math.inf, "best_epoch": 0, "bad_epochs": 0,
                          "wall_s": 0.0, "history": []}
    best = {k: v.detach().clone() for k, v in net.state_dict().items()}
    if resume:
        if ckpt is None or not (ckpt / "checkpoint.json").exists():
            raise ModelFileError(f"--resume: no checkpoint in {ckpt}")
        best, st = _load_checkpoint(ckpt, net, opt)
        sched.last_epoch = st["epoch"]
        for g, lr in zip(opt.param_groups, sched.get_lr()):
            g["lr"] = lr
    t0 = time.perf_counter() - st["wall_s"]
    stop_reason = "epochs"
    with Bar(cfg.epochs, f"cikan train {name or arch.family}", "epochs", progress,
             completed=st["epoch"]) as bar:
        while st["epoch"] < cfg.epochs:
            ep = st["epoch"]
            ep_start = time.perf_counter()
            net.train()
            perm = torch.from_numpy(np.random.default_rng([cfg.seed, ep]).permutation(n_train))
            total, count = 0.0, 0
            for i in range(0, n_train, cfg.batch):
                idx = perm[i:i + cfg.batch]
                loss = cinn_log_loss(net(z_train[idx]), yt[idx], cfg.theta_c)
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                total += loss.item() * len(idx)
                count += len(idx)
            sched.step()
            p_val = predict(net, z["val"])
            val = cinn_log_loss_np(p_val, data.splits["val"].y, cfg.theta_c)
            val1 = cinn_log_loss_np(p_val, data.splits["val"].y, 1.0)
            st["epoch"] = ep + 1
            st["history"].append({"epoch": ep + 1, "train_loss": total / count, "val_loss": val,
                                  "val_loss_theta1": val1,
                                  "lr": opt.param_groups[0]["lr"]})
            if val < st["best_val"] * (1 - 1e-4):
                st.update(best_val=val, best_epoch=ep + 1, bad_epochs=0)
                best = {k: v.detach().clone() for k, v in net.state_dict().items()}
            else:
                st["bad_epochs"] += 1
            st["wall_s"] = time.perf_counter() - t0
            if ckpt is not None:
                _save_checkpoint(ckpt, net, opt, best, st)
            bar.advance(1, note=f"val {val:.2e}, best {st['best_val']:.2e}")
            if on_epoch is not None:
                on_epoch(ep + 1, val1)
            if st["bad_epochs"] >= cfg.patience:
                stop_reason = "early stopping"
                break
            epoch_s = time.perf_counter() - ep_start
            if cfg.max_minutes > 0 and st["wall_s"] + epoch_s > cfg.max_minutes * 60:
                stop_reason = "wall budget"
                break
    net.load_state_dict(best)
    # y - y_hat is the same for both targets (their offset cancels): the losses compare.
    losses = {"definition": "mean((y - y_hat)^2) + theta_c * mean(relu(y - y_hat)^2), y = ln|tau*| [s]"
                            + (" - ln|tau_{k-1}|" if arch.relative else ""),
              "theta_c": cfg.theta_c}
    for s in SPLITS:
        zs = z[s][:n_train] if s == "train" else z[s]
        sd = data.splits[s]
        if s == "train":
            sd = sd.head(n_train)
        losses[s] = split_report(net, zs, sd, cfg.theta_c)
    training = {
        "optimizer": "AdamW", "schedule": "ExpHyperbolicLR (per epoch)",
        **{k: v for k, v in asdict(cfg).items() if k != "extra"}, **cfg.extra,
        "upper_bound": cfg.upper_bound or cfg.epochs,
        "epochs_run": st["epoch"], "best_epoch": st["best_epoch"], "stop_reason": stop_reason,
        "history": st["history"],
        "cpu_budget": {"wall_s": round(st["wall_s"], 3), "max_minutes": cfg.max_minutes,
                       "torch_threads": cfg.threads, "cpu": _cpu_name(),
                       "cpus_on_machine": os.cpu_count()},
    }
    if out is not None:
        meta = {k: v for k, v in data.meta.items() if k != "config"}
        card = {"name": name or arch.family, "family": arch.family,
                "scenario": card_scenario(data.meta),
                "labels": label_config(data.meta.get("config") or {}),
                "dataset": {"file": Path(data.path).name, **meta, "train_labels_used": n_train},
                "config": data.meta.get("config"),
                "losses": losses, "training": training, "versions": library_versions(),
                **(card_extra or {})}
        save_model(out, arch, net.state_dict(), card)
    return {"losses": losses, "training": training, "net": net}


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    import platform

    return platform.processor() or "unknown"
