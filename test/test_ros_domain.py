"""skin_node.ros_domain: a claimed domain is held by no other live process."""
import socket
import subprocess
import sys

import pytest

from skin_node.ros_domain import (DEFAULT_RANGE, RANGE_ENV, bound_udp_ports, claim_domain,
                                  domain_ports, domain_range)


def test_range_from_the_environment_or_the_default(monkeypatch):
    monkeypatch.delenv(RANGE_ENV, raising=False)
    assert domain_range() == range(DEFAULT_RANGE[0], DEFAULT_RANGE[1] + 1)
    monkeypatch.setenv(RANGE_ENV, "60-79")
    assert domain_range() == range(60, 80)
    assert domain_range("7") == range(7, 8)
    for bad in ("60-", "a-b", "79-60", "0-300"):
        with pytest.raises(ValueError, match=RANGE_ENV):
            domain_range(bad)


def test_ports_of_a_domain_follow_the_rtps_mapping():
    # domain 0: discovery multicast 7400, the first participant's unicast 7410/7411
    assert domain_ports(0) == range(7400, 7650)
    assert domain_ports(60) == range(22400, 22650)
    # every domain of the default range stays below Linux' ephemeral ports
    assert domain_ports(DEFAULT_RANGE[1]).stop <= 32768


def test_claims_exclude_each_other_and_are_released(tmp_path):
    domains = range(20, 24)
    claims = [claim_domain(domains, tmp_path) for _ in domains]
    assert sorted(c.domain for c in claims) == list(domains)
    with pytest.raises(RuntimeError, match="no free ROS domain in 20-23"):
        claim_domain(domains, tmp_path)
    freed = claims.pop(1)
    freed.release()
    with claim_domain(domains, tmp_path) as again:
        assert again.domain == freed.domain
    for c in claims:
        c.release()


def test_a_claim_held_by_another_process_is_skipped(tmp_path):
    domains = range(30, 32)
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import sys; from skin_node.ros_domain import claim_domain; "
         f"c = claim_domain(range(30, 31), {str(tmp_path)!r}); print(c.domain, flush=True); "
         "sys.stdin.read()"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "30"
        for _ in range(3):
            with claim_domain(domains, tmp_path) as c:
                assert c.domain == 31
    finally:
        holder.communicate("", timeout=30)
    assert holder.returncode == 0
    with claim_domain(range(30, 31), tmp_path) as c:     # the holder is gone: free again
        assert c.domain == 30


def test_a_domain_whose_ports_are_bound_is_skipped(tmp_path):
    # A participant that takes no lock (a node started by hand) still binds its
    # domain's ports; pick a domain whose first port this test can bind.
    busy = bound_udp_ports()
    domain = next(d for d in range(40, 99) if not busy.intersection(domain_ports(d)))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", domain_ports(domain)[11]))
        assert domain_ports(domain)[11] in bound_udp_ports()
        with pytest.raises(RuntimeError):
            claim_domain(range(domain, domain + 1), tmp_path)
    with claim_domain(range(domain, domain + 1), tmp_path) as c:
        assert c.domain == domain
