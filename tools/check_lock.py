"""Fails (exit 1, one line per difference) when this interpreter's packages differ from a lock file.

`make venv` runs it after installing the lock, so a venv that silently kept other versions (a reused
.venv, a pip cache with newer wheels) is caught before any test runs on an untested combination.
"""

from __future__ import annotations

import re
import sys
from importlib import metadata
from pathlib import Path

PIN = re.compile(r"^([A-Za-z0-9][A-Za-z0-9._-]*)==([^\s;#]+)")


def normalise(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def differences(lock: Path) -> list[str]:
    installed = {normalise(d.metadata["Name"]): d.version for d in metadata.distributions()}
    problems = []
    for line in lock.read_text().splitlines():
        match = PIN.match(line)
        if not match:
            continue
        name, wanted = normalise(match[1]), match[2]
        have = installed.get(name)
        if have != wanted:
            problems.append(f"{name}: lock {wanted}, venv {have or 'missing'}")
    return problems


def main() -> int:
    lock = Path(sys.argv[1])
    problems = differences(lock)
    for problem in problems:
        print(f"ERROR: venv differs from {lock}: {problem}", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
