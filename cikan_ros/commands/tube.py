"""``cikan tube``: robust Verify's error-tube constants of a configuration and the FTRE loop's gain
margin (``cikan_ros.robust``; the figures docs/robustness.md quotes)."""

from __future__ import annotations

import argparse

from . import add_config_args, config_from_args


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("tube", help="robust Verify's tube constants and the FTRE loop's gain margin",
                       description="Print (JSON) the control weights, the FTRE loop's gain margin and "
                                   "the error-tube constants of robust Verify for the configuration's "
                                   "declared thruster errors (docs/robustness.md); declared errors "
                                   "that destabilise the loop are reported under 'unstable'.")
    add_config_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json
    import math

    from ..config import control_config
    from ..orbit import KeplerOrbit
    from ..robust import UnstableLoopError, gain_margin, tube_constants

    cfg = config_from_args(args)
    orbit = KeplerOrbit.from_config(cfg.orbit)
    truth = cfg.truth
    control = control_config(cfg)
    out: dict[str, object] = {"r_diag": list(control.r_diag), "gain_margin": gain_margin(orbit, control)}
    try:
        out.update(tube_constants(orbit, control, truth.bound("thrust_bias_max"),
                                  math.radians(truth.bound("thrust_pointing_max_deg"))))
    except UnstableLoopError as exc:
        out["unstable"] = str(exc)
    print(json.dumps(out, indent=1))
    return 0
