"""Two hosts on one machine: network namespaces joined by a veth pair, each process with its own /dev/shm.

A process started on a host (:meth:`TwoHosts.popen`) sees only that namespace's network (the veth
end and loopback) and a private tmpfs at ``/dev/shm``, so DDS cannot take the shared-memory path
between the hosts and every frame crosses the "wire" as UDP, as between two computers. Needs root
(``ip netns``, ``mount``); :func:`unavailable` says why when it cannot run.

    sudo python bench/two_hosts.py ../shared/data/tum_fr3_teddy    # bag_player on one, slam_node on the other
"""

from __future__ import annotations

import argparse
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.bench_replay_loss import final_counts

__all__ = ["TwoHosts", "unavailable"]

_SUBNET = "10.77.{n}.{host}"


def unavailable() -> str | None:
    """Why two hosts cannot be made here (None: they can)."""
    if os.geteuid() != 0:
        return "needs root (network namespaces and a tmpfs per host)"
    for tool in ("ip", "unshare", "mount"):
        if shutil.which(tool) is None:
            return f"needs the {tool} command"
    try:  # a container may allow namespaces but not veth pairs or mounts: try the whole set-up once
        with TwoHosts() as hosts:
            probe = hosts.popen("a", ["true"], dict(os.environ), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
            _, err = probe.communicate(timeout=30)
            if probe.returncode != 0:
                return f"cannot give a host its own /dev/shm: {err.decode(errors='replace').strip()}"
    except subprocess.CalledProcessError as err:
        return f"cannot make the hosts ({' '.join(err.cmd)}): {(err.stderr or '').strip()}"
    except (OSError, subprocess.TimeoutExpired) as err:
        return f"cannot make the hosts: {err}"
    return None


class TwoHosts:
    """Hosts ``a`` and ``b`` (network namespaces) joined by a veth pair on a /24 of their own."""

    def __init__(self) -> None:
        tag = f"{os.getpid() % 10000}{random.randint(0, 99)}"
        self.names = {"a": f"sgsa{tag}", "b": f"sgsb{tag}"}
        self.subnet = random.randint(1, 250)
        self.procs: list[subprocess.Popen] = []

    def _ip(self, *args: str) -> None:
        subprocess.run(["ip", *args], check=True, capture_output=True, text=True)

    def __enter__(self) -> TwoHosts:
        try:
            self._make()
        except BaseException:
            self.__exit__()  # what was made goes again
            raise
        return self

    def _make(self) -> None:
        a, b = self.names["a"], self.names["b"]
        self._ip("netns", "add", a)
        self._ip("netns", "add", b)
        self._ip("link", "add", f"v{a}", "netns", a, "type", "veth", "peer", "name", f"v{b}", "netns", b)
        for host, name in self.names.items():
            address = _SUBNET.format(n=self.subnet, host=1 if host == "a" else 2)
            self._ip("-n", name, "addr", "add", f"{address}/24", "dev", f"v{name}")
            self._ip("-n", name, "link", "set", "lo", "up")
            self._ip("-n", name, "link", "set", f"v{name}", "up")
            self._ip("-n", name, "route", "add", "224.0.0.0/4", "dev", f"v{name}")  # DDS discovery: multicast

    def popen(self, host: str, argv: list[str], env: dict[str, str], **kwargs: object) -> subprocess.Popen:
        """Start ``argv`` on ``host`` with a private /dev/shm."""
        shell = 'mount -t tmpfs -o size=1g tmpfs /dev/shm && exec "$@"'
        cmd = ["ip", "netns", "exec", self.names[host], "unshare", "--mount", "--propagation", "private"]
        cmd += ["sh", "-c", shell, "sh", *argv]
        proc = subprocess.Popen(cmd, env=env, **kwargs)
        self.procs.append(proc)
        return proc

    def __exit__(self, *exc: object) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=30)
        for name in self.names.values():
            subprocess.run(["ip", "netns", "del", name], capture_output=True, check=False)


def host_env(profile: Path | None = None) -> dict[str, str]:
    """A process's environment on one of the hosts: discovery across the subnet, a fresh ROS set-up.

    ``profile``: a Fast DDS profile of the caller's (default: each process applies the shipped one).
    """
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET", ROS_DOMAIN_ID=str(random.randint(1, 100)))
    env.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)  # let the child set up its own library path
    env.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
    if profile is not None:
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(profile)
    return env


def play_across(
    hosts: TwoHosts,
    bag: Path,
    node_params: list[str],
    remaps: list[str],
    timeout_s: float = 300.0,
    profile: Path | None = None,
) -> dict[str, float]:
    """``bag_player`` on host a into ``slam_node`` on host b; the node's final counts and the frames sent (``sent``)."""
    env = host_env(profile)
    py = sys.executable
    args = [a for p in node_params for a in ("-p", p)] + [a for r in remaps for a in ("-r", r)]
    node = hosts.popen(
        "b",
        [py, "-m", "sgs_slam_ros.slam_node", "--ros-args", "-p", "save_on_shutdown:=false", *args],
        env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    player = hosts.popen(
        "a",
        [py, "-m", "sgs_slam_ros.bag_player", str(bag), "--wait", "120"],
        env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    player_log = player.communicate(timeout=timeout_s)[0]
    time.sleep(3.0)  # the last frames' callbacks
    node.send_signal(signal.SIGINT)  # to `ip netns exec`, which passes it on (exec all the way down)
    node_log = node.communicate(timeout=120)[0]
    return final_counts(node_log, player_log)


def main() -> int:
    from bench.common import append_section, markdown_table  # noqa: PLC0415 - only for the benchmark

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("input", type=Path, help="a TUM/ScanNet folder (converted to a bag at full size) or a bag")
    p.add_argument("--downscale", type=float, default=4.0, help="slam_node's processing size")
    p.add_argument("--preset", default="tum")
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--profile", type=Path, help="a Fast DDS profile for both hosts (default: the shipped one)")
    p.add_argument("--no-append", action="store_true")
    args = p.parse_args()
    why = unavailable()
    if why is not None:
        print(f"two_hosts: {why}", file=sys.stderr)
        return 1
    from bags.format import is_bag  # noqa: PLC0415

    work = Path(tempfile.mkdtemp(prefix="two-hosts-"))
    try:
        bag = args.input
        if not is_bag(bag):
            bag = work / "bag"
            cmd = [sys.executable, "-m", "bags.cli", "convert", str(args.input), "--out", str(bag)]
            subprocess.run([*cmd, "--compress", "none"], check=True, capture_output=True, text=True)
        params = [f"preset:={args.preset}", f"downscale:={args.downscale}", "use_semantics:=false"]
        rows = []
        for r in range(args.repeats):
            with TwoHosts() as hosts:
                c = play_across(hosts, bag, params, REMAPS, profile=args.profile)
            lost = c["sent"] - c["frames_in"]
            row = [r + 1, c["sent"], c["frames_in"], c.get("frames_lost", 0), lost, c["frames_tracked"]]
            rows.append([*row, f"{100 * lost / max(c['sent'], 1):.1f} %"])
            print(rows[-1], flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    table = markdown_table(
        ["run", "frames sent", "frames_in", "frames_lost (counted)", "sent - in", "frames_tracked", "lost"], rows
    )
    body = (
        f"`{args.input.name}` at its recorded size and rate from `bag_player` on one host into `slam_node` "
        f"(downscale {args.downscale:g}, semantics off) on another: two network namespaces joined by a veth "
        f"pair, each with its own /dev/shm; Fast DDS profile: {args.profile or 'the shipped one'}.\n\n{table}\n"
    )
    print(body)
    if not args.no_append:
        append_section("Two hosts: frames across the network", body)
    return 0


REMAPS = [
    "rgb/image:=/camera/color/image_raw",
    "depth/image:=/camera/depth/image_raw",
    "rgb/camera_info:=/camera/color/camera_info",
]

if __name__ == "__main__":
    raise SystemExit(main())
