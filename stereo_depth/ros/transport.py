"""Fast DDS transport for large messages, chosen for our own processes when the user chose none.

Why (measured, docs/dds.md#large-messages): Fast DDS's default shared-memory segment is
512 KB per publishing process, so a 9.8 MB points2 (or a 921 KB colour image) goes over fragmented
UDP instead, where a 30 Hz stream reaches a subscriber at 18-20 Hz. The segment belongs to the
*publisher*: a publisher with config/fastdds_large_images.xml reaches a subscriber on Fast DDS
defaults (RViz, Nav2) at the full rate. So every process of ours that publishes (the nodes, replay,
the bench) loads that profile itself, unless a profile is already exported or another RMW is chosen.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping
from pathlib import Path

PROFILE_NAME = "fastdds_large_images.xml"
# Jazzy's Fast DDS 2.14 reads the first; Fast DDS 3 (later ROS releases) the second.
PROFILE_VARIABLES = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


def large_message_profile() -> Path | None:
    """The profile shipped with the package: the source tree's config/, or an install prefix's
    share/stereo_depth/config/ (colcon); None if neither is there."""
    for folder in Path(__file__).resolve().parents:
        for candidate in (
            folder / "config" / PROFILE_NAME,
            folder / "share" / "stereo_depth" / "config" / PROFILE_NAME,
        ):
            if candidate.is_file():
                return candidate
    return None


def use_large_message_profile(environ: MutableMapping[str, str] | None = None) -> Path | None:
    """Point Fast DDS at our profile for this process (call before rclpy.init); returns the profile
    used, or None when the user's own choice stands (a profile exported, or an RMW other than Fast DDS)."""
    env = os.environ if environ is None else environ
    if not env.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp").startswith("rmw_fastrtps"):
        return None
    if any(env.get(name) for name in PROFILE_VARIABLES):
        return None
    profile = large_message_profile()
    if profile is None:
        return None
    for name in PROFILE_VARIABLES:
        env[name] = str(profile)
    return profile
