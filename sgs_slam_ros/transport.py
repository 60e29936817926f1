"""The DDS transport for camera images between processes on one machine (Fast DDS shared memory).

Fast DDS's built-in shared-memory transport uses 512 KiB segments, smaller than one 640x480 colour
image; such images then travel as UDP fragments over loopback, and many 30 Hz frames are lost
between processes. ``config/fastdds_shm.xml`` gives each participant a shared-memory segment that
holds whole frames (UDPv4 stays beside it for discovery and other machines). Fast DDS reads the
profile named by ``FASTRTPS_DEFAULT_PROFILES_FILE`` when the process's first participant is made,
so it must be set before ``rclpy.init``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

__all__ = ["PROFILE_ENV", "TRANSPORTS", "apply_transport", "profile_path"]

PROFILE_ENV = "FASTRTPS_DEFAULT_PROFILES_FILE"
PROFILE_NAME = "fastdds_shm.xml"
TRANSPORTS = ("shm", "default")
_PACKAGE = "sgs_slam_ros"


def profile_path() -> Path | None:
    """The shipped profile: beside the sources (checkout, editable install) or in the install's share/."""
    candidates = [
        Path(__file__).resolve().parents[1] / "config" / PROFILE_NAME,
        Path(sys.prefix) / "share" / _PACKAGE / "config" / PROFILE_NAME,
    ]
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / "share" / _PACKAGE / "config" / PROFILE_NAME)
    return next((p for p in candidates if p.is_file()), None)


def apply_transport(choice: str) -> str:
    """Make ``choice`` this process's transport (call before ``rclpy.init``); returns what was done, in words.

    ``shm``: the shipped shared-memory profile, unless the user already named a profile (kept) or
    runs another RMW than Fast DDS (nothing to do). ``default``: Fast DDS's built-in transports.
    """
    if choice not in TRANSPORTS:
        raise ValueError(f"transport must be one of {', '.join(TRANSPORTS)}, got {choice!r}")
    if choice == "default":
        return "Fast DDS built-in transports"
    rmw = os.environ.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    if not rmw.startswith("rmw_fastrtps"):
        return f"{rmw}'s own transports (the shared-memory profile is for Fast DDS)"
    if os.environ.get(PROFILE_ENV):
        return f"the Fast DDS profile in {PROFILE_ENV}={os.environ[PROFILE_ENV]}"
    path = profile_path()
    if path is None:
        return f"Fast DDS built-in transports ({PROFILE_NAME} not found beside the package)"
    os.environ[PROFILE_ENV] = str(path)
    return f"Fast DDS shared memory ({path})"
