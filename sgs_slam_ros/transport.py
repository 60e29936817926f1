"""The DDS transport for camera images between processes on one machine (Fast DDS shared memory).

Fast DDS's built-in shared-memory transport uses 512 KiB segments, smaller than one 640x480 colour
image; such images then travel as UDP fragments over loopback, and many 30 Hz frames are lost
between processes. ``config/fastdds_shm.xml`` gives each participant a shared-memory segment that
holds whole frames (UDPv4 stays beside it for discovery and other machines). Fast DDS reads the
profile named by ``FASTRTPS_DEFAULT_PROFILES_FILE`` when the process's first participant is made,
so it must be set before ``rclpy.init``.

Between computers the frames travel over UDP, and a socket buffer smaller than a frame loses
frames: the profile asks for 4 MiB buffers, which Linux grants only up to ``net.core.rmem_max`` /
``wmem_max`` (about 208 KiB on a stock host). :func:`socket_buffer_advice` compares the two and
names the ``sysctl`` that fixes a host that is short.
"""

from __future__ import annotations

import os
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

__all__ = [
    "PROFILE_ENV",
    "TRANSPORTS",
    "apply_transport",
    "profile_path",
    "profile_socket_buffers",
    "socket_buffer_advice",
]

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


_HOST_LIMITS = {"receiveBufferSize": "rmem_max", "sendBufferSize": "wmem_max"}  # profile element -> sysctl
PROC_NET_CORE = Path("/proc/sys/net/core")


def profile_socket_buffers(profile: Path) -> dict[str, int]:
    """The largest UDP ``receiveBufferSize`` / ``sendBufferSize`` (bytes) a Fast DDS profile asks for.

    Empty when the profile sets none or cannot be read (Fast DDS reports a broken profile itself).
    """
    try:
        root = ET.parse(profile).getroot()
    except (OSError, ET.ParseError):
        return {}
    sizes: dict[str, int] = {}
    for element in root.iter():
        name = element.tag.rsplit("}", 1)[-1]
        if name in _HOST_LIMITS and (element.text or "").strip().isdigit():
            sizes[name] = max(sizes.get(name, 0), int(element.text.strip()))
    return sizes


def socket_buffer_advice(profile: Path | None, proc: Path | None = None) -> str | None:
    """One line naming the ``sysctl`` to run when the host caps socket buffers below the profile's; else None.

    ``proc``: where ``rmem_max`` and ``wmem_max`` are read (default :data:`PROC_NET_CORE`).
    """
    if profile is None:
        return None
    proc = PROC_NET_CORE if proc is None else proc
    short = []
    for element, size in sorted(profile_socket_buffers(profile).items()):
        key = _HOST_LIMITS[element]
        try:
            limit = int((proc / key).read_text().strip())
        except (OSError, ValueError):
            continue  # not Linux, or not readable: nothing to say
        if limit < size:
            short.append((key, limit, size))
    if not short:
        return None
    found = ", ".join(f"{key} {limit}" for key, limit, _ in short)
    need = max(size for _, _, size in short)
    fix = " ".join(f"net.core.{key}={need}" for key in ("rmem_max", "wmem_max"))
    return (
        f"this host caps UDP socket buffers ({found} bytes) below the {need} the DDS profile asks for: "
        f"frames from other computers will be lost; fix: sudo sysctl -w {fix} (persist it in /etc/sysctl.d/)"
    )
