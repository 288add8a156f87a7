"""Hyper-parameter search with Optuna (TPE sampler, median pruning), SPEC §7.

Each trial trains one network for a short schedule on (a prefix of) the training split and is
scored by its best validation loss in the paper's definition at θ_c = 1 (so trials with different
θ_c compare). Intermediate validation losses are reported every epoch; the median pruner stops
poor trials early. The study lives in an Optuna storage (a SQLite file by default; any RDB URL
lets several processes or machines share one study: each `cikan tune` adds its trials).

Search spaces are bounded so a network's single-sample forward stays in tens of microseconds
(the governor's budget): KAN widths 8-48, MLP widths 32-256, 2-5 layers.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from .arch import KAN_FAMILIES, Arch
from .train import Data, TrainConfig, train

DEFAULT_STORAGE = "sqlite:///runs/tune.sqlite3"


def study_name_for(family: str, features: str = "vnb", scenario: str = "paper", approach: str = "behind") -> str:
    """The default Optuna study of a family, feature set, scenario and approach side, the one rule
    ``cikan tune`` (which creates it) and ``cikan train --study`` (which reads it) both follow:
    ``cikan-tsg-FAMILY[-FEATURES][-SCENARIO-APPROACH]``, the state-only features ("vnb") and the
    paper's scenario from behind keeping the short name. A scenario given as a file is named by
    its ``scenario.name`` (the file's stem unless it sets one)."""
    name = f"cikan-tsg-{family}" + ("" if features == "vnb" else f"-{features}")
    return name if (scenario, approach) == ("paper", "behind") else f"{name}-{scenario}-{approach}"


def suggest(trial: Any, family: str, features: str = "vnb") -> tuple[Arch, dict[str, Any]]:
    """Architecture and training hyper-parameters of one trial."""
    if family in KAN_FAMILIES:
        arch = Arch(family, width=trial.suggest_categorical("width", [8, 16, 24, 32, 48]),
                    layers=trial.suggest_int("layers", 2, 4), grid=trial.suggest_int("grid", 4, 16),
                    grid_range=trial.suggest_float("grid_range", 2.0, 4.0), features=features)
        if family != "cikan":
            spacing = 2 * arch.grid_range / (arch.grid - 1)
            arch = replace(arch, h=spacing * trial.suggest_float("h_over_spacing", 0.5, 2.0, log=True))
    else:
        arch = Arch(family, width=trial.suggest_categorical("width", [32, 64, 128, 256]),
                    layers=trial.suggest_int("layers", 2, 5), features=features)
    hp = {
        "lr": trial.suggest_float("lr", 3e-4, 1e-2, log=True),
        "weight_decay": trial.suggest_float("weight_decay", 1e-7, 1e-3, log=True),
        "theta_c": trial.suggest_float("theta_c", 0.25, 4.0, log=True),
        "batch": trial.suggest_categorical("batch", [256, 512, 1024]),
    }
    return arch, hp


def arch_and_hp_from_params(params: dict[str, Any], family: str, features: str = "vnb"
                            ) -> tuple[Arch, dict[str, Any]]:
    """Rebuild a trial's architecture and hyper-parameters from its ``params`` (best trial)."""
    import optuna

    trial = optuna.trial.FixedTrial(params)
    return suggest(trial, family, features)


def run_tune(family: str, data: Data, trials: int, storage: str = DEFAULT_STORAGE,
             study_name: str | None = None, epochs: int = 8, max_train: int = 40000,
             trial_minutes: float = 2.0, seed: int | None = None, threads: int = 1,
             timeout_s: float | None = None, progress: bool = False) -> dict[str, Any]:
    """Add ``trials`` trials to the study of ``family`` in ``storage``; return a summary."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    name = study_name or study_name_for(family, data_features(data))
    study = optuna.create_study(
        study_name=name, storage=open_storage(storage), direction="minimize", load_if_exists=True,
        sampler=optuna.samplers.TPESampler(seed=seed, n_startup_trials=4, multivariate=True),
        pruner=optuna.pruners.MedianPruner(n_startup_trials=2, n_warmup_steps=2))

    def objective(trial: optuna.Trial) -> float:
        arch, hp = suggest(trial, family, data_features(data))
        cfg = TrainConfig(epochs=epochs, patience=epochs, max_minutes=trial_minutes,
                          max_train=max_train, threads=threads, seed=trial.number, **hp)

        def on_epoch(epoch: int, val: float) -> None:
            trial.report(val, epoch)
            if trial.should_prune():
                raise optuna.TrialPruned()

        res = train(arch, data, cfg, out=None, progress=progress, on_epoch=on_epoch,
                    name=f"{family} trial {trial.number}")
        trial.set_user_attr("n_params", arch.n_params())
        trial.set_user_attr("epochs_run", res["training"]["epochs_run"])
        trial.set_user_attr("wall_s", res["training"]["cpu_budget"]["wall_s"])
        return float(res["losses"]["val"]["loss_theta1"])

    study.optimize(objective, n_trials=trials, timeout=timeout_s, gc_after_trial=True)
    return study_summary(study)


def open_storage(url: str, attempts: int = 6) -> Any:
    """An Optuna RDB storage. SQLite waits up to 60 s on a lock; creating the schema of a new
    database from several processes at once can race ("table ... already exists", a duplicate
    alembic version row): retried."""
    import random
    import time

    import optuna
    import sqlalchemy.exc

    kwargs = {"connect_args": {"timeout": 60}} if url.startswith("sqlite") else {}
    for attempt in range(attempts):
        try:
            return optuna.storages.RDBStorage(url, engine_kwargs=kwargs)
        except (sqlalchemy.exc.OperationalError, sqlalchemy.exc.IntegrityError):
            if attempt == attempts - 1:
                raise
            time.sleep(0.2 + random.random())
    raise AssertionError("unreachable")  # pragma: no cover


def data_features(data: Data) -> str:
    return data.features


def study_summary(study: Any) -> dict[str, Any]:
    """Counts of trials by state and the best trial (value, params)."""
    from optuna.trial import TrialState

    states = [t.state for t in study.trials]
    out: dict[str, Any] = {
        "study": study.study_name,
        "trials": len(states),
        "complete": states.count(TrialState.COMPLETE),
        "pruned": states.count(TrialState.PRUNED),
        "failed": states.count(TrialState.FAIL),
    }
    done = [t for t in study.trials if t.state == TrialState.COMPLETE]
    if done:
        best = study.best_trial
        out.update(best_value=best.value, best_params=best.params, best_trial=best.number,
                   best_user_attrs=best.user_attrs,
                   trial_wall_s_total=sum(t.user_attrs.get("wall_s", 0.0) for t in study.trials))
    return out
