"""Summaries say what was flown (scenario, side, truth, Verify, governor and model, docking test,
network acceptance), show each quantity in one unit, and a final distance below what float64 ECI
positions resolve as such."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

#: Short missions: what the summary says is under test, not how the mission ends.
SHORT = ["--set", "mission.duration_s=600"]


def cikan(*args: str, cwd: str | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "COLUMNS": "250"}   # rich wraps tables at the terminal width
    return subprocess.run([sys.executable, "-m", "cikan_ros.cli", *args], capture_output=True, text=True,
                          timeout=300, env=env, cwd=cwd)


def rows(table: str) -> dict[str, str]:
    """{label: value} of a rich table printed with box characters."""
    out = {}
    for line in table.splitlines():
        cells = [c.strip() for c in line.split("│")[1:-1]]
        if len(cells) == 2:
            out[cells[0]] = cells[1]
    return out


def test_final_distance_below_float64_resolution(cfg):
    """At the epoch the paper's chief is at periapsis, |r| = a (1 - e): ECI positions there are
    resolved to eps a (1 - e); a distance below that is printed as such, one above as a number."""
    from cikan_ros.analysis.flown import distance_text, eci_resolution_m

    res = eci_resolution_m(cfg, 0.0)
    assert res == pytest.approx(np.finfo(float).eps * cfg.orbit.a_km * (1 - cfg.orbit.e) * 1e3, rel=1e-12)
    assert distance_text(0.4 * res, res) == f"< {res:.2g} (float64 resolution of ECI positions)"
    assert distance_text(3.0 * res, res) == f"{3.0 * res:.3e}"
    assert distance_text(None, res) == "-"


def test_mission_summary_names_what_flew():
    out = cikan("mission", "--offline", "--seed", "1", "--scenario", "leo", "--set", "mission.approach=ahead",
                "--truth", "realistic", *SHORT)
    assert out.returncode in (0, 1), out.stderr
    r = rows(out.stdout)
    assert r["scenario"].startswith("leo: ISS orbit")
    assert r["approach"] == "from ahead (τ >= 0, cone 20° around +v_c)"
    assert r["truth"].startswith("realistic at scale 1 (j2 gravity, thrust bias <= 2 %")
    assert r["Verify"] == "nominal"
    assert r["governor"] == "conventional"
    assert r["docking test"] == "< 0.1 m, < 0.01 m/s at the end, τ = 0, no violation"
    # h2 under the 2 % bias bound: against u_lim = 0.5 m/s^2 x 1.02; h3 in m/s
    assert "max h2 = |u| - u_lim [m/s²], u_lim = 0.51 m/s² = u_max (1 + bias 0.02)" in r
    assert "max h3 [m/s]" in r and not any("km/s]" in k and "h3" in k for k in r)
    assert "network acceptance" not in r


def test_learned_mission_summary_names_its_model_and_acceptance():
    """Under robust Verify a family flies its model of robust Verify's labels (models/cikan-robust);
    at another truth scale that model is refused with one line and exit code 2; flown when allowed,
    its summary names it foreign, with its acceptance."""
    flown = ["--offline", "--seed", "3", "--governor", "cikan", "--truth", "realistic", "--robust", *SHORT]
    own = cikan("mission", *flown)
    assert own.returncode in (0, 1), own.stderr
    r = rows(own.stdout)
    assert r["governor"].rstrip(")").endswith("models/cikan-robust") and "model" not in r   # not foreign
    flown += ["--set", "truth.scale=0.5"]
    refused = cikan("mission", *flown)
    assert refused.returncode == 2 and len(refused.stderr.strip().splitlines()) == 1
    assert ("trained on labels of robust Verify (truth realistic at scale 1.0, controller R = 1e+07, ancillary tube), "
            "not of robust Verify (truth realistic at scale 0.5, controller R = 1e+07, ancillary tube) "
            "(differs: truth.scale)") in refused.stderr
    flown += ["--set", "learned.foreign_model=true"]
    out = cikan("mission", *flown)
    js = cikan("mission", *flown, "--json")
    assert out.returncode in (0, 1) and js.returncode in (0, 1), out.stderr + js.stderr
    r = rows(out.stdout)
    assert r["governor"].startswith("cikan (model ") and r["governor"].rstrip(")").endswith("models/cikan-robust")
    rate = json.loads(js.stdout)["nn_accept_rate"]
    assert r["network acceptance"] == f"{rate:.3f} (nn_accept_rate)"
    assert r["Verify"] == "robust (constraints tightened by the truth's bounds)"
    assert r["model"].startswith("FOREIGN: trained on labels of robust Verify (truth realistic at scale 1.0")
    assert json.loads(js.stdout)["foreign_model"].endswith("(differs: truth.scale)")


def test_montecarlo_summary_names_what_flew_in_one_unit(tmp_path):
    out = cikan("montecarlo", "--runs", "1", "--governor", "conventional,cikan", "--out", str(tmp_path / "mc"),
                *SHORT)
    assert out.returncode == 0, out.stderr
    text = (tmp_path / "mc" / "summary.md").read_text()
    assert text in out.stdout
    assert "- scenario: paper:" in text and "- approach: from behind" in text and "- Verify: nominal" in text
    assert "- governor: conventional, cikan (" in text and "- docking test: < 1 m" in text

    def refuse(name: str) -> None:
        raise ValueError(f"not strict JSON: {name}")

    summary = json.loads((tmp_path / "mc" / "summary.json").read_text(), parse_constant=refuse)
    head, _, *lines = [ln for ln in text.splitlines() if ln.startswith("|")]
    columns = [c.strip() for c in head.split("|")[1:-1]]
    assert "max h3 (m/s)" in columns and "NN accept" in columns
    for line in lines:
        cells = dict(zip(columns, (c.strip() for c in line.split("|")[1:-1])))
        s = summary[cells["governor"]]
        h3 = s["max_h3"]
        assert cells["max h3 (m/s)"] == ("-" if h3 is None else f"{1e3 * h3:.2e}")
        rate = s["nn_accept_rate_mean"]
        assert cells["NN accept"] == ("-" if rate is None or math.isnan(rate) else f"{rate:.3f}")
    assert summary["conventional"]["nn_accept_rate_mean"] is None
    assert summary["cikan"]["nn_accept_rate_mean"] is not None
