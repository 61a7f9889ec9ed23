"""A ROS_DOMAIN_ID that no other run on this host holds, for test runs (test/conftest.py) and the benches
that talk DDS: each run locks one for its lifetime, so two runs at once (two checkouts, CI beside a
developer, a bench beside the tests) never see each other's nodes and topics.
"""

from __future__ import annotations

import fcntl
import os
import tempfile
from pathlib import Path
from typing import IO

DOMAIN_IDS = 100  # 1..100: ids whose DDS ports are valid on Linux
_LOCKS: list[IO[str]] = []  # held (open) until the process ends


def claim_domain_id() -> int:
    first = os.getpid() % DOMAIN_IDS
    for offset in range(DOMAIN_IDS):
        domain = (first + offset) % DOMAIN_IDS + 1
        lock = (Path(tempfile.gettempdir()) / f"stereo_depth_test_domain_{domain}.lock").open("w")
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            lock.close()
            continue
        _LOCKS.append(lock)
        return domain
    msg = f"all {DOMAIN_IDS} ROS domain ids are held by other runs on this host"
    raise RuntimeError(msg)


def isolate_on_this_host() -> str:
    """Loopback discovery, and the ROS_DOMAIN_ID the user exported or else a free one (locked); set in
    os.environ for this process and those it starts. Returns the domain id."""
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    if not os.environ.get("ROS_DOMAIN_ID"):
        os.environ["ROS_DOMAIN_ID"] = str(claim_domain_id())
    return os.environ["ROS_DOMAIN_ID"]
