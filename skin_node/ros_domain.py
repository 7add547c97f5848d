"""A ROS_DOMAIN_ID that no other live process on this host is using.

Two runs on one domain hear each other's joint states and skins. A pid-derived
domain does not prevent that (two pids can land on the same one, and a node
left over from an earlier run keeps its domain), so a domain is *claimed*:

* an exclusive, non-blocking lock (``fcntl.flock``) on
  ``<tmp>/ros_domain_<id>.lock``, held for the life of the claim; the kernel
  drops it when its process dies, so a crash never leaves a stale claim
  behind, and two claims in one process exclude each other too;
* and none of the domain's DDS ports bound on this host: RTPS gives domain
  ``d`` the UDP ports ``7400 + 250 d`` up to the next domain's, and every
  participant binds some of them, so a node started by hand, or one whose
  claimant died, still marks its domain busy.

``SKIN_NODE_DOMAINS=lo-hi`` narrows the range scanned (for instance to the
domains one user owns on a shared machine); the default is 10-99, clear of the
usual default domain 0 and below 101, the highest domain whose ports Linux
keeps out of its ephemeral range.
"""
from __future__ import annotations

import fcntl
import itertools
import os
import re
import tempfile
from pathlib import Path

RANGE_ENV = "SKIN_NODE_DOMAINS"
DEFAULT_RANGE = (10, 99)
#: RTPS port mapping (DDSI-RTPS 2.x, 9.6.1.1): port base PB and domain gain DG.
PORT_BASE, DOMAIN_GAIN = 7400, 250

_claims = itertools.count()


def domain_range(spec: str | None = None) -> range:
    """The domains to scan: ``spec`` or ``$SKIN_NODE_DOMAINS`` (``"lo-hi"``,
    inclusive, or one number), else :data:`DEFAULT_RANGE`.

    Raises
    ------
    ValueError
        When the spec is not ``lo-hi`` with 0 <= lo <= hi <= 232.
    """
    spec = os.environ.get(RANGE_ENV, "") if spec is None else spec
    if not spec.strip():
        lo, hi = DEFAULT_RANGE
    else:
        m = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", spec)
        if m is None:
            raise ValueError(f"{RANGE_ENV}={spec!r}: expected 'lo-hi', e.g. '60-79'")
        lo, hi = int(m[1]), int(m[2] or m[1])
        if not 0 <= lo <= hi <= 232:
            raise ValueError(f"{RANGE_ENV}={spec!r}: need 0 <= lo <= hi <= 232")
    return range(lo, hi + 1)


def bound_udp_ports() -> set[int]:
    """Local UDP ports bound on this host (empty where /proc/net says nothing)."""
    ports = set()
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if len(fields) > 1:
                ports.add(int(fields[1].rpartition(":")[2], 16))
    return ports


def domain_ports(domain: int) -> range:
    """The UDP ports RTPS gives ``domain``: discovery and data, every participant."""
    return range(PORT_BASE + DOMAIN_GAIN * domain, PORT_BASE + DOMAIN_GAIN * (domain + 1))


class DomainClaim:
    """A claimed domain: ``domain`` is this process's until :meth:`release`.

    Use it as a context manager, or keep it for the life of the process.
    """

    def __init__(self, domain: int, fd: int) -> None:
        self.domain, self._fd = domain, fd

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)          # closing drops the lock
            self._fd = None

    def __enter__(self) -> "DomainClaim":
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def __repr__(self) -> str:
        return f"DomainClaim({self.domain}{'' if self._fd is not None else ', released'})"


def claim_domain(domains: range | None = None, lock_dir: str | Path | None = None) -> DomainClaim:
    """Claim a domain of ``domains`` (default :func:`domain_range`) that no other
    live process holds or uses; see the module docstring.

    The scan starts at a different domain for each process and each claim, so a
    domain just released is not handed out again at once (the participants of
    its last user may still be in other processes' discovery caches).

    Raises
    ------
    RuntimeError
        When every domain of the range is taken.
    """
    domains = domain_range() if domains is None else domains
    lock_dir = Path(lock_dir or tempfile.gettempdir())
    start = (os.getpid() + next(_claims)) % len(domains)
    busy = bound_udp_ports()
    for k in range(len(domains)):
        domain = domains[(start + k) % len(domains)]
        if busy.intersection(domain_ports(domain)):
            continue
        try:
            fd = os.open(lock_dir / f"ros_domain_{domain}.lock", os.O_RDWR | os.O_CREAT, 0o666)
        except OSError:                 # another user's lock file: theirs
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:                 # held by a live claim
            os.close(fd)
            continue
        # Ports bound between the scan and the lock belong to someone who does
        # not lock: look once more now that no claimant can race us.
        if bound_udp_ports().intersection(domain_ports(domain)):
            os.close(fd)
            continue
        return DomainClaim(domain, fd)
    raise RuntimeError(f"no free ROS domain in {domains.start}-{domains.stop - 1} "
                       f"(all locked under {lock_dir} or in use); widen {RANGE_ENV}")
