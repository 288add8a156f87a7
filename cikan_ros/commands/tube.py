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
                                   "that destabilise the loop are reported under 'unstable'. Under "
                                   "the ancillary tube, 'ancillary' lists each gain band's tracking "
                                   "loop (least range, weight, lam, |K_p|, |K_v|, the l1 norms over "
                                   "the geometric bound per block, C0, the DC gains G and the transient's "
                                   "envelope).")
    add_config_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json
    import math

    from ..config import ancillary_band_configs, ancillary_control_config, control_config
    from ..orbit import KeplerOrbit
    from ..robust import UnstableLoopError, gain_margin, tube_constants

    cfg = config_from_args(args)
    orbit = KeplerOrbit.from_config(cfg.orbit)
    truth = cfg.truth
    control = control_config(cfg)
    out: dict[str, object] = {"r_diag": list(control.r_diag), "gain_margin": gain_margin(orbit, control)}
    try:
        # the scalar constants (the transient envelopes, per power, stay in the library)
        out.update({k: v for k, v in tube_constants(orbit, control, truth.bound("thrust_bias_max"),
                                                    math.radians(truth.bound("thrust_pointing_max_deg"))).items()
                    if not k.startswith("env")})
    except UnstableLoopError as exc:
        out["unstable"] = str(exc)
    if cfg.tsg.robust and cfg.tsg.tube == "ancillary":
        bands = []
        for km, band in ancillary_band_configs(cfg):
            track = ancillary_control_config(band)
            row: dict[str, object] = {"from_km": km, "r_diag": list(track.r_diag)}
            try:
                tc = tube_constants(orbit, track, truth.bound("thrust_bias_max"),
                                    math.radians(truth.bound("thrust_pointing_max_deg")))
                row.update({k: tc[k] for k in ("lam", "kp", "kv")})
                blocks = ("pp", "pv", "vp", "vv")
                # what the l1 bound (tsg.ancillary_bound l1) takes of the geometric one, per block,
                # and the transient's envelope against C0 (docs/robustness.md, "The l1 bound")
                row["l1_over_geometric"] = {
                    k: tc[f"l{k}"] / (tc[k] / (1.0 - tc["lam"]))
                    for k in [f"cn{b}" for b in blocks] + [f"d{b}" for b in blocks] + ["cpe", "cve"]}
                row["c0"] = {b: tc[f"c0{b}"] for b in blocks}
                row["g"] = {b: tc[f"g{b}"] for b in blocks}  # the DC gains of a lasting navigation offset
                envelopes = {b: tc[f"env{b}"] for b in blocks}
                row["envelope"] = {b: {"peak": max(e), "at": e.index(max(e)), "m1": e[1]} for b, e in envelopes.items()}
            except UnstableLoopError as exc:
                row["unstable"] = str(exc)
            bands.append(row)
        out["ancillary"] = bands
    print(json.dumps(out, indent=1))
    return 0
