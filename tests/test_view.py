"""The mission-control view (``cikan view``, ``cikan mission --view``): bad input is one line and
exit code 2; a Monte Carlo directory is overlaid; and, in headless Chromium (Debian's chromium
driven by playwright; skipped with one line without it), a recorded bag shows the 3D scene and
the plots without a console error, the slider moves the deputy to the LVLH position an
independent computation gives, and a live mission's plots grow as it flies."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest

from cikan_ros.cli import main
from cikan_ros.config import load_config

from ros_helpers import ros_env  # noqa: F401  (fixture)

ROOT = Path(__file__).resolve().parents[1]
BAG = ROOT / "bags" / "nominal_conventional"
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
DEPUTY = "document.getElementById('scene').data.find(t => t.name === 'deputy')"


# -- without a browser ---------------------------------------------------------------------------
@pytest.mark.parametrize("make", ["empty", "not_a_bag", "truncated", "missing"])
def test_bad_input_is_one_line_and_exit_code_2(make: str, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    path = tmp_path / make
    if make == "empty":
        path.mkdir()
    elif make == "not_a_bag":
        path.write_text("not a bag\n")
    elif make == "truncated":
        shutil.copytree(BAG, path)
        mcap = next(path.glob("*.mcap"))
        os.truncate(mcap, mcap.stat().st_size // 2)
    assert main(["view", str(path), "--no-browser"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("cikan view: error: ") and err.count("\n") == 1, err


def test_mission_view_needs_the_ros_graph(capsys: pytest.CaptureFixture) -> None:
    """--view follows the bag of a ROS run: --offline records none, one line."""
    assert main(["mission", "--offline", "--view"]) == 2
    assert capsys.readouterr().err == "cikan mission: error: --view follows the bag of the ROS graph; --offline records none\n"


def test_montecarlo_directory_overlays_its_runs(tmp_path: Path) -> None:
    """Every flown run of every governor is drawn (its own time axis and LVLH path), the
    telemetry carries the configuration's limits, the cone the run's half angle."""
    from cikan_ros.montecarlo import run_campaign
    from cikan_ros.view.data import load

    cfg = load_config(**{"mission.duration_s": 300.0, "constraints.los_half_angle_deg": 25.0})
    run_campaign(cfg, ["conventional"], 2, 1, tmp_path, progress=False)
    data = load(tmp_path)
    assert data["kind"] == "montecarlo" and [r["label"] for r in data["runs"]] == \
        ["conventional seed 1", "conventional seed 2"]
    assert data["scene"]["half_angle_deg"] == 25.0
    thrust = next(p for p in data["telemetry"] if p["key"] == "thrust")
    assert thrust["limit_high"] == pytest.approx(cfg.control.u_max_kmps2 * 1e3)
    for run in data["runs"]:
        assert len(run["t"]) == 31 and run["t"][0] == 0.0 and run["t"][-1] == 300.0
        assert np.asarray(run["deputy"]).shape == (3, 31)


# -- in the browser ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def browser_context(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    """A headless Chromium with a fresh profile; skipped with one line without chromium."""
    if not CHROMIUM.exists():
        pytest.skip(f"no {CHROMIUM}: `make browser` installs Debian's chromium (as root)")
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright missing (the dev extra)")
    with sync_api.sync_playwright() as pw:
        context = pw.chromium.launch_persistent_context(
            str(tmp_path_factory.mktemp("chromium-profile")), executable_path=str(CHROMIUM),
            args=CHROMIUM_ARGS, headless=True)
        yield context
        context.close()


def start_view(*args: str) -> tuple[subprocess.Popen, str]:
    """``cikan view ARGS --no-browser`` in its own process, and its URL."""
    proc = subprocess.Popen([sys.executable, "-m", "cikan_ros.cli", "view", *args, "--no-browser"],
                            stdout=subprocess.PIPE, text=True)
    with proc.stdout:
        line = proc.stdout.readline()
    assert line.startswith("cikan view: http://127.0.0.1:"), line
    return proc, line.split()[2]


def open_page(context: Any, url: str) -> tuple[Any, list[str]]:
    """A page on ``url`` and the list its console errors and page errors go to."""
    page = context.new_page()
    errors: list[str] = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url)
    return page, errors


def lvlh_position_m(x_d: np.ndarray, x_c: np.ndarray) -> np.ndarray:
    """p_rel in the chief's LVLH frame (x radial, z orbit normal, y = z x x), m: written out here."""
    r, v = x_c[:3], x_c[3:]
    x = r / np.linalg.norm(r)
    z = np.cross(r, v) / np.linalg.norm(np.cross(r, v))
    y = np.cross(z, x)
    return np.array([x, y, z]) @ (x_d[:3] - x_c[:3]) * 1e3


def test_a_bag_in_the_browser(browser_context: Any) -> None:
    from ros_helpers import rosbags_messages, states

    proc, url = start_view(str(BAG))
    try:
        page, errors = open_page(browser_context, url)
        page.wait_for_function("window.cikanView && window.cikanView.ready", timeout=60_000)
        assert page.locator("#scene canvas").count() > 0          # the WebGL scene is drawn
        names = page.evaluate("document.getElementById('scene').data.map(t => t.name)")
        assert {"deputy", "virtual target", "docking port (chief)"} <= set(names)
        assert any(n.startswith("line-of-sight cone (20°, behind)") for n in names)
        plots = page.evaluate("document.getElementById('plots').data.map(t => [t.name, t.x.length])")
        assert ["conventional", 1441] in plots and sum(1 for n, _ in plots if n == "limit") >= 5
        before = page.evaluate(f"[{DEPUTY}.x[0], {DEPUTY}.y[0], {DEPUTY}.z[0]]")
        page.locator("#slider").fill("700")
        page.wait_for_function(f"{DEPUTY}.x[0] !== {before[0]}", timeout=10_000)
        after = page.evaluate(f"[{DEPUTY}.x[0], {DEPUTY}.y[0], {DEPUTY}.z[0]]")
        msgs = rosbags_messages(BAG)
        t_d, x_d = states(msgs, "/deputy/odom")
        _, x_c = states(msgs, "/chief/odom")
        for k, shown in ((0, before), (700, after)):
            np.testing.assert_allclose(shown, lvlh_position_m(x_d[k], x_c[k]), rtol=1e-6, atol=1e-6)
        assert page.inner_text("#time").startswith("t = 1 h 56 min 40 s")   # step 700 of T_c = 10 s
        page.locator("#slider").fill("1440")      # the end: tau = 0, the virtual target is the chief
        page.wait_for_function(f"{DEPUTY}.x[0] !== {after[0]}", timeout=10_000)
        target = page.evaluate("(t => [t.x[0], t.y[0], t.z[0]])(document.getElementById('scene').data"
                               ".find(t => t.name === 'virtual target'))")
        assert np.linalg.norm(target) < 1e-3, target   # m
        assert not errors, errors
    finally:
        proc.terminate()
        proc.wait()


def test_a_live_mission_in_the_browser(browser_context: Any, ros_env: int, tmp_path: Path) -> None:  # noqa: F811
    """The view process `cikan mission --view` starts follows the bag as the recorder flushes it:
    the page's plots hold more and more steps while the mission flies (paced to 10 s wall), and
    all of them at its end."""
    from cikan_ros.ros.launch import run_ros_mission
    from cikan_ros.view.live import start_view_process

    cfg = load_config(**{"mission.duration_s": 1200.0})
    bag = tmp_path / "bag"
    proc, url = start_view_process(bag, 0, browser=False)
    result: dict[str, Any] = {}
    flight = threading.Thread(target=lambda: result.update(run_ros_mission(
        cfg, bag=bag, node_params={"sim.max_rtf": 120.0})))
    try:
        page, errors = open_page(browser_context, url)
        flight.start()
        counts: list[int] = []
        deadline = time.monotonic() + 120.0
        while time.monotonic() < deadline:
            n = page.evaluate("window.cikanView.ready ? document.getElementById('plots').data[0].x.length : 0")
            if n and (not counts or n != counts[-1]):
                counts.append(n)
            # complete once the page draws the whole mission (not when the data arrives: the
            # plots are redrawn after it, and the count read above may precede that)
            if page.evaluate("!!(window.cikanView.shown && window.cikanView.shown.complete)"):
                n = page.evaluate("document.getElementById('plots').data[0].x.length")
                if not counts or n != counts[-1]:
                    counts.append(n)
                break
            page.wait_for_timeout(200)
        flight.join(60.0)
        assert result.get("steps", result.get("ros", {}).get("steps")) == 120, result
        assert counts and counts[-1] == 121, counts           # t_0 .. t_120, all of them
        assert len(counts) >= 3 and counts == sorted(counts), counts   # it grew as the mission flew
        assert not errors, errors
    finally:
        proc.terminate()
        proc.wait()
        flight.join(60.0)
