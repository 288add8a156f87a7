"""``cikan train``: train one network family on a label dataset and write a model directory."""

from __future__ import annotations

import argparse
from typing import Any

from ..learn.arch import TARGETS
from ..learn.features import FEATURE_SETS
from ..strict_json import dumps
from . import add_config_args, config_from_args, seed_arg

FAMILY_HELP = "cikan (B-spline KAN), grbf, rswaf, relu (MLP), gelu (MLP)"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("train", help="train a learned governor network",
                       description="Train a network (AdamW, ExpHyperbolicLR, constraint-informed "
                                   "log loss) on a dataset from `cikan dataset`; the best epoch by "
                                   "validation loss is written as model.safetensors + card.json.")
    p.add_argument("--model", required=True, choices=("cikan", "grbf", "rswaf", "relu", "gelu"),
                   help=FAMILY_HELP)
    p.add_argument("--data", default=["runs/dataset.parquet"], nargs="+", metavar="PATH",
                   help="dataset (Parquet); several are concatenated, each label in its own "
                        "file's split (e.g. conventional plus on-policy labels)")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="model directory, e.g. models/my_cikan (default: the scenario's, "
                        "scenario.models_dir/<family>[-ahead][-robust]; the dataset must be of that scenario, "
                        "side and Verify)")
    add_config_args(p)
    p.add_argument("--study", metavar="URL", default=None,
                   help="take architecture and hyper-parameters from the best trial of the Optuna "
                        "study in this storage (see `cikan tune`); explicit options override them")
    p.add_argument("--study-name", default=None,
                   help="study name (default cikan-tsg-MODEL[-FEATURES][-SCENARIO-APPROACH]: the one "
                        "`cikan tune` created for this model, features, scenario and side)")
    p.add_argument("--like", metavar="MODEL", default=None,
                   help="take architecture and hyper-parameters from this model's card (a shipped "
                        "family or a model directory of the same family), e.g. to train the "
                        "paper's tuned network on another scenario; explicit options override them")
    g = p.add_argument_group("architecture")
    g.add_argument("--width", type=int, default=None, help="hidden width n")
    g.add_argument("--layers", type=int, default=None, help="layers l (maps)")
    g.add_argument("--grid", type=int, default=None, help="grid G (KAN)")
    g.add_argument("--grid-range", type=float, default=None, help="grid covers [-R, R] (KAN)")
    g.add_argument("--h", type=float, default=None, help="basis width h (GRBF, RSWAF; 0 = spacing)")
    g.add_argument("--no-hidden-norm", action="store_true", help="no LayerNorm on hidden KAN inputs")
    g.add_argument("--features", default="vnb", choices=FEATURE_SETS, help="feature set")
    g.add_argument("--target", default="log-shift", choices=TARGETS,
                   help="what the network learns: ln|tau*| (log-shift, the paper's) or "
                        "ln(|tau*| / |tau_{k-1}|) (log-ratio: pi*'s step from the last shift; needs "
                        "--features vnb-prev; docs/learned_update_rule.md, \"A network of the step\")")
    t = p.add_argument_group("training")
    t.add_argument("--epochs", type=int, default=40,
                   help="epochs N of the schedule (0: write the untrained network, its seeded "
                        "random initial weights, e.g. to test the keep rule against a network that does not fit)")
    t.add_argument("--upper-bound", type=int, default=0, help="ExpHyperbolicLR U >= N (0: N)")
    t.add_argument("--lr", type=float, default=None, help="initial learning rate")
    t.add_argument("--lr-inf", type=float, default=None, help="final learning rate (default lr/100)")
    t.add_argument("--weight-decay", type=float, default=None)
    t.add_argument("--batch", type=int, default=None)
    t.add_argument("--theta-c", type=float, default=None, help="weight of the ReLU^2 term")
    t.add_argument("--patience", type=int, default=8, help="early stopping patience (epochs)")
    t.add_argument("--seed", type=seed_arg, default=0)
    t.add_argument("--max-minutes", type=float, default=0.0, help="wall-clock budget (0: none)")
    t.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    t.add_argument("--max-train", type=int, default=0, help="use the first N training labels (0: all)")
    t.add_argument("--checkpoint-dir", default=None, metavar="DIR",
                   help="checkpoints (default runs/checkpoints/<out name>)")
    t.add_argument("--resume", action="store_true", help="continue from the checkpoint")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the losses as one JSON object")
    p.set_defaults(func=run)


def like_model(name: str, family: str, features: str) -> tuple[Any, dict]:
    """(architecture, hyper-parameters) of an existing model's card, for ``--like``."""
    from dataclasses import replace

    from ..learn.errors import ModelFileError
    from ..learn.modelfile import load_model

    model = load_model(name)
    if model.arch.family != family:
        raise ModelFileError(f"--like {name}: that model is a {model.arch.family}, not a {family}")
    training = model.card.get("training") or {}
    hp = {k: training[k] for k in ("lr", "weight_decay", "batch", "theta_c") if k in training}
    if len(hp) != 4:
        raise ModelFileError(f"--like {name}: its card lacks the training hyper-parameters")
    return replace(model.arch, features=features, n_in=0), hp


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace
    from pathlib import Path

    from ..learn.arch import Arch
    from ..learn.train import TrainConfig, load_data, train
    from ..progress import on_terminal

    hp: dict = {"lr": 3e-3, "weight_decay": 1e-5, "batch": 512, "theta_c": 1.0}
    arch = Arch(args.model, width=32 if args.model in ("cikan", "grbf", "rswaf") else 128, layers=3,
                features=args.features)
    extra: dict = {}
    if args.like and args.study:
        from ..errors import ConfigError

        raise ConfigError("--like and --study both choose the hyper-parameters: give one")
    if args.like:
        arch, hp = like_model(args.like, args.model, args.features)
        extra["like"] = args.like
    if args.study:
        import optuna

        from ..learn.tune import arch_and_hp_from_params, study_name_for, study_summary

        optuna.logging.set_verbosity(optuna.logging.WARNING)
        cfg_run = config_from_args(args)
        name = args.study_name or study_name_for(args.model, args.features, cfg_run.scenario.name,
                                                 cfg_run.mission.approach)
        try:
            study = optuna.load_study(study_name=name, storage=args.study)
        except KeyError:
            from ..learn.errors import DatasetError

            raise DatasetError(f"no Optuna study {name!r} in {args.study}") from None
        summary = study_summary(study)
        if "best_params" not in summary:
            from ..learn.errors import DatasetError

            raise DatasetError(f"study {name!r} has no complete trial")
        arch, hp = arch_and_hp_from_params(summary["best_params"], args.model, args.features)
        extra["tuning"] = {k: v for k, v in summary.items()}
    changes = {k: v for k, v in (("width", args.width), ("layers", args.layers), ("grid", args.grid),
                                 ("grid_range", args.grid_range), ("h", args.h)) if v is not None}
    if args.no_hidden_norm:
        changes["hidden_norm"] = False
    arch = replace(arch, **changes, target=args.target)
    for k in ("lr", "weight_decay", "batch", "theta_c"):
        if getattr(args, k) is not None:
            hp[k] = getattr(args, k)
    cfg = TrainConfig(epochs=args.epochs, upper_bound=args.upper_bound,
                      lr_inf=args.lr_inf if args.lr_inf is not None else hp["lr"] / 100,
                      patience=args.patience, seed=args.seed, max_minutes=args.max_minutes,
                      threads=args.threads, max_train=args.max_train, **hp)
    data = load_data(args.data, args.features, args.target)
    if args.out is None:
        from ..learn.modelfile import check_dataset_labels, check_dataset_scenario, scenario_model_dir

        cfg_run = config_from_args(args)
        check_dataset_scenario(data.meta, data.path, cfg_run.scenario.name, cfg_run.mission.approach)
        check_dataset_labels(data.meta, data.path, cfg_run.flat())
        args.out = str(scenario_model_dir(cfg_run.scenario.models_dir, args.model, cfg_run.mission.approach,
                                          cfg_run.tsg.robust))
    ckpt = args.checkpoint_dir or str(Path("runs/checkpoints") / Path(args.out).name)
    res = train(arch, data, cfg, args.out, checkpoint_dir=ckpt, resume=args.resume,
                progress=on_terminal(args.quiet or args.json), name=Path(args.out).name, card_extra=extra)
    losses = res["losses"]
    if args.json:
        print(dumps({"out": args.out, "architecture": arch.to_dict(), "n_params": arch.n_params(),
                     "complexity": arch.complexity(), "losses": losses,
                     "epochs_run": res["training"]["epochs_run"],
                     "wall_s": res["training"]["cpu_budget"]["wall_s"]}))
    else:
        print(f"wrote {args.out}: {arch.family} (n={arch.width}, l={arch.layers}, G={arch.grid}), "
              f"{arch.n_params()} parameters, complexity {arch.complexity()}")
        for s in ("train", "val", "test"):
            if losses.get(s):
                print(f"  {s:5s} loss {losses[s]['loss']:.4e}  (theta_c=1: {losses[s]['loss_theta1']:.4e})"
                      f"  RMSE(tau) {losses[s]['rmse_tau_s']:.4f} s  labels {losses[s]['labels']}")
    return 0
