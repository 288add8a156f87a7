"""Which ROS domain a graph flies on: one that no other live graph on this machine uses.

Processes on one ROS_DOMAIN_ID hear each other: two graphs on one domain mix their topics (the
states of one reach the governor of the other) and their readiness announcements. So every graph
the launcher starts holds a *lease* on its domain for as long as it runs:

- an exclusive lock (``flock``) on one file per domain in a directory every cikan process of this
  machine shares (``$CIKAN_ROS_LOCK_DIR``, default ``/tmp/cikan_ros_domains``): two leases of one
  domain never coexist, and the kernel releases a lease when its holder dies, however it dies;
- a domain of the pool whose Fast DDS ports are bound is skipped: a ROS process that took no
  lease (any other ROS program, a test session of an older checkout) is using it.

``$CIKAN_ROS_DOMAINS`` (``LO-HI``, default ``1-101``: the IDs whose ports lie below Linux's
ephemeral range) is the pool leases are drawn from, starting at a random place in it.
``$CIKAN_ROS_DOMAIN_ID`` pins one domain instead: it is leased if it is free; if this process or
one of its ancestors holds its lease (a test that leased it and launches graphs in it), it is used
by one graph at a time (a second lock, per graph); it is refused with one line if another live
process holds it. Its ports are not probed: above domain 101 they lie in Linux's ephemeral range,
where any program's short-lived socket may hold one for a moment (measured: a pinned domain 151
was refused dozens of times in a row while no ROS process used it). Domains 0-232 are accepted
(Fast DDS ends a process on 233 or more).
"""

from __future__ import annotations

import fcntl
import os
import random
import socket
from pathlib import Path

from ..errors import CikanError

#: Pool of domains leased from unless ``$CIKAN_ROS_DOMAINS`` says otherwise.
DEFAULT_POOL = (1, 101)
#: Highest domain Fast DDS accepts (its ports must fit in 16 bits).
MAX_DOMAIN = 232
#: Fast DDS's well-known ports (RTPS): PB + DG * domain + offset + PG * participant id.
_PB, _DG, _PG, _D1, _D3 = 7400, 250, 2, 10, 11
#: Participants probed per domain (a graph of four nodes uses ids 0-3; tests add a few).
_PROBED_PARTICIPANTS = 16


def lock_dir() -> Path:
    """The directory of the lease files (shared by every cikan process of the machine)."""
    return Path(os.environ.get("CIKAN_ROS_LOCK_DIR") or "/tmp/cikan_ros_domains")


def _domain(text: str, name: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise CikanError(f"{name} must be a ROS domain id (0..{MAX_DOMAIN}), got {text!r}") from None
    if not 0 <= value <= MAX_DOMAIN:
        raise CikanError(f"{name} must lie in 0..{MAX_DOMAIN}, got {value}")
    return value


def pool() -> tuple[int, int]:
    """``$CIKAN_ROS_DOMAINS`` as (lo, hi), inclusive; DEFAULT_POOL if unset."""
    text = os.environ.get("CIKAN_ROS_DOMAINS", "").strip()
    if not text:
        return DEFAULT_POOL
    lo, sep, hi = text.partition("-")
    if not sep:
        raise CikanError(f"CIKAN_ROS_DOMAINS must be a range LO-HI of ROS domain ids, got {text!r}")
    lo_id, hi_id = _domain(lo.strip(), "CIKAN_ROS_DOMAINS"), _domain(hi.strip(), "CIKAN_ROS_DOMAINS")
    if lo_id > hi_id:
        raise CikanError(f"CIKAN_ROS_DOMAINS: {lo_id} > {hi_id}")
    return lo_id, hi_id


def ports_in_use(domain: int) -> bool:
    """True if a Fast DDS participant of ``domain`` has bound its unicast ports on this machine."""
    base = _PB + _DG * domain
    for pid in range(_PROBED_PARTICIPANTS):
        for offset in (_D1, _D3):
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                try:
                    s.bind(("0.0.0.0", base + offset + _PG * pid))
                except OSError:
                    return True
    return False


def _ancestors() -> set[int]:
    """This process and its ancestors (from /proc)."""
    out, pid = set(), os.getpid()
    while pid > 1 and pid not in out:
        out.add(pid)
        try:
            stat = Path(f"/proc/{pid}/stat").read_text()
            pid = int(stat.rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            break
    return out


class DomainLease:
    """A held ROS domain (see the module docstring); ``release()`` or leave the ``with`` block."""

    def __init__(self, domain: int, fd: int | None) -> None:
        self.domain, self._fd = domain, fd

    def fds(self) -> tuple[int, ...]:
        """The lock's descriptor, for child processes to inherit: the lease then lasts until the
        last of them ends too (a launcher killed outright leaves nodes that end a moment later)."""
        return () if self._fd is None else (self._fd,)

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)   # closing the descriptor drops the lock
            self._fd = None

    def __del__(self) -> None:
        self.release()

    def __enter__(self) -> "DomainLease":
        return self

    def __exit__(self, *_exc: object) -> None:
        self.release()


def _try_lock(domain: int, kind: str = "domain") -> tuple[int | None, str]:
    """(descriptor holding the domain's lock of this kind, "") or (None, the holder's pid text)."""
    d = lock_dir()
    d.mkdir(mode=0o777, parents=True, exist_ok=True)
    path = d / f"{kind}_{domain}.lock"
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        try:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip()
        finally:
            os.close(fd)
        return None, holder
    os.ftruncate(fd, 0)
    os.pwrite(fd, str(os.getpid()).encode(), 0)
    return fd, ""


def lease_domain() -> DomainLease:
    """Lease a domain for a graph: ``$CIKAN_ROS_DOMAIN_ID`` if set, else a free one of the pool."""
    pinned = os.environ.get("CIKAN_ROS_DOMAIN_ID", "").strip()
    if pinned:
        domain = _domain(pinned, "CIKAN_ROS_DOMAIN_ID")
        fd, holder = _try_lock(domain)
        if fd is None:
            if not (holder.isdigit() and int(holder) in _ancestors()):
                raise CikanError(f"ROS domain {domain} (CIKAN_ROS_DOMAIN_ID) is in use by another graph "
                                 f"(process {holder or 'unknown'}): choose another, or unset "
                                 "CIKAN_ROS_DOMAIN_ID to get a free one")
            # Leased by an ancestor (a test): one graph at a time flies on it.
            fd, holder = _try_lock(domain, "graph")
            if fd is None:
                raise CikanError(f"ROS domain {domain} (CIKAN_ROS_DOMAIN_ID) already carries a graph "
                                 f"(process {holder or 'unknown'}): one graph per domain")
        return DomainLease(domain, fd)
    lo, hi = pool()
    start = random.SystemRandom().randint(lo, hi)
    for i in range(hi - lo + 1):
        domain = lo + (start - lo + i) % (hi - lo + 1)
        fd, _ = _try_lock(domain)
        if fd is None:
            continue
        if ports_in_use(domain):
            os.close(fd)
            continue
        return DomainLease(domain, fd)
    raise CikanError(f"no free ROS domain in {lo}..{hi} (CIKAN_ROS_DOMAINS): every one is leased or in use")
