"""Two graphs on one machine never share a ROS domain (cikan_ros.ros.domain): leases are
exclusive across processes, a domain whose DDS ports are bound is skipped, a pinned domain held by
another live process is refused with one line, and two missions launched at once fly on two
domains (real processes, real DDS), each bag holding its own mission only."""

from __future__ import annotations

import contextlib
import json
import os
import socket
import subprocess
import sys
from pathlib import Path
from typing import Iterator

import pytest

from cikan_ros.errors import CikanError
from cikan_ros.ros import domain as dom
from cikan_ros.ros.bag_reader import check_messages, read_bag
from ros_helpers import ros_env

__all__ = ["ros_env"]
CIKAN = Path(sys.executable).parent / "cikan"
#: A child process that leases a domain (as its environment says), prints it, and holds it until
#: its stdin closes.
HOLDER = "import sys; from cikan_ros.ros.domain import lease_domain; l = lease_domain(); " \
         "print(l.domain, flush=True); sys.stdin.read()"


@pytest.fixture
def pool(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Leases in a private lock directory (no other session's leases), pool 220-222 (no graph of
    this machine flies there: the default pool is 1-101, the tests' too unless CIKAN_ROS_DOMAINS)."""
    monkeypatch.setenv("CIKAN_ROS_LOCK_DIR", str(tmp_path / "locks"))
    monkeypatch.setenv("CIKAN_ROS_DOMAINS", "220-222")
    monkeypatch.delenv("CIKAN_ROS_DOMAIN_ID", raising=False)
    return tmp_path / "locks"


@contextlib.contextmanager
def holder(env: dict[str, str]) -> Iterator[tuple[subprocess.Popen, int]]:
    """A child process holding a lease: (process, its domain); it ends when the block does."""
    with subprocess.Popen([sys.executable, "-c", HOLDER], env=env, stdin=subprocess.PIPE,
                          stdout=subprocess.PIPE, text=True) as proc:
        try:
            yield proc, int(proc.stdout.readline())
        finally:
            proc.stdin.close()
            proc.wait()


def test_leases_are_exclusive_until_released(pool: Path) -> None:
    leases = [dom.lease_domain() for _ in range(3)]
    assert sorted(lease.domain for lease in leases) == [220, 221, 222]
    with pytest.raises(CikanError, match=r"^no free ROS domain in 220\.\.222 \(CIKAN_ROS_DOMAINS\)"):
        dom.lease_domain()
    leases[1].release()
    again = dom.lease_domain()
    assert again.domain == leases[1].domain
    for lease in (leases[0], leases[2], again):
        lease.release()


def test_a_domain_held_by_another_process_is_never_leased(pool: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    with holder({**os.environ, "CIKAN_ROS_DOMAINS": "221-221"}) as (proc, held):
        assert held == 221
        leases = [dom.lease_domain(), dom.lease_domain()]
        assert sorted(lease.domain for lease in leases) == [220, 222]
        for lease in leases:
            lease.release()
        monkeypatch.setenv("CIKAN_ROS_DOMAIN_ID", "221")   # pinned: refused, one line naming the holder
        with pytest.raises(CikanError, match=rf"^ROS domain 221 \(CIKAN_ROS_DOMAIN_ID\) is in use by "
                                             rf"another graph \(process {proc.pid}\): choose another"):
            dom.lease_domain()
    with dom.lease_domain() as lease:   # its holder has ended: free again
        assert lease.domain == 221


def test_a_domain_whose_ports_are_bound_is_skipped(pool: Path) -> None:
    """A ROS process that took no lease (another program) is seen by its bound RTPS port."""
    port = 7400 + 250 * 220 + 10 + 2 * 3       # participant 3's metatraffic unicast port
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("0.0.0.0", port))
        assert dom.ports_in_use(220) and not dom.ports_in_use(221)
        leases = [dom.lease_domain(), dom.lease_domain()]
        assert sorted(lease.domain for lease in leases) == [221, 222]
        for lease in leases:
            lease.release()


def test_a_test_and_its_graph_share_a_lease_one_graph_at_a_time(pool: Path) -> None:
    """A pinned domain whose lease an ancestor holds (a test leasing it for its graph) is used,
    by one graph at a time."""
    with dom.lease_domain() as mine:
        env = {**os.environ, "CIKAN_ROS_DOMAIN_ID": str(mine.domain)}
        with holder(env) as (proc, held):               # a child: its ancestor (this test) holds it
            assert held == mine.domain
            child = subprocess.run([sys.executable, "-c", HOLDER], env=env, input="", capture_output=True,
                                   text=True)       # a second graph on it at the same time: refused
            assert child.returncode == 1
            assert f"ROS domain {mine.domain} (CIKAN_ROS_DOMAIN_ID) already carries a graph (process " \
                   f"{proc.pid}): one graph per domain" in child.stderr


@pytest.mark.parametrize("spec, problem", [
    ("x", "CIKAN_ROS_DOMAIN_ID must be a ROS domain id (0..232), got 'x'"),
    ("233", "CIKAN_ROS_DOMAIN_ID must lie in 0..232, got 233"),
])
def test_bad_pinned_domain_is_one_line(spec: str, problem: str, tmp_path: Path) -> None:
    env = {**os.environ, "CIKAN_ROS_DOMAIN_ID": spec, "CIKAN_ROS_LOCK_DIR": str(tmp_path)}
    out = subprocess.run([str(CIKAN), "mission", "--set", "mission.duration_s=60", "--bag",
                          str(tmp_path / "bag")], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 2 and out.stderr.strip().splitlines() == [f"cikan mission: error: {problem}"]


@pytest.mark.parametrize("spec", ["5", "9-3", "1-300"])
def test_bad_pool_is_one_line(spec: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CIKAN_ROS_DOMAINS", spec)
    with pytest.raises(CikanError, match="^CIKAN_ROS_DOMAINS"):
        dom.pool()


def test_two_missions_at_once_fly_on_two_domains(ros_env: int, tmp_path: Path) -> None:
    """`cikan mission` twice at the same moment, each leasing from the pool: two domains, and each
    bag holds exactly its own mission (one message per step and topic, none twice)."""
    from cikan_ros.config import load_config

    env = {k: v for k, v in os.environ.items() if k != "CIKAN_ROS_DOMAIN_ID"}
    env["TMPDIR"] = str(tmp_path)
    procs = [subprocess.Popen([str(CIKAN), "mission", "--json", "--set", "mission.duration_s=60", "--bag",
                               str(tmp_path / f"bag{i}")], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for i in range(2)]
    results = [p.communicate(timeout=600) for p in procs]
    for p, (out, err) in zip(procs, results):
        assert p.returncode == 1, err          # a 60-s mission does not dock: failed, not an error
    domains = {json.loads(out)["ros"]["domain_id"] for out, _ in results}
    assert len(domains) == 2 and ros_env not in domains   # the test's own lease is skipped too
    cfg = load_config(**{"mission.duration_s": 60.0})
    for i in range(2):
        check = check_messages(read_bag(tmp_path / f"bag{i}"), cfg, 6)
        assert (check["lost"], check["duplicated"], check["off_grid"]) == (0, 0, 0), check
