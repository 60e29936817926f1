"""Two hosts on one machine: network namespaces joined by a veth pair, each host with its own /dev/shm.

A process started on a host (:meth:`TwoHosts.popen`) sees only that namespace's network (the veth
end and loopback) and that host's tmpfs at ``/dev/shm`` (shared with the host's other processes, as
on a computer, not with the other host's), so DDS cannot take the shared-memory path
between the hosts and every frame crosses the "wire" as UDP, as between two computers. Needs root
(``ip netns``, ``mount``); :func:`unavailable` says why when it cannot run.

    sudo python bench/two_hosts.py ../shared/data/tum_fr3_teddy    # bag_player on one, slam_node on the other
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

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

    def __init__(self, cpus: dict[str, str] | None = None) -> None:
        """``cpus``: the CPUs of each host's processes (``taskset`` lists, e.g. {"a": "0", "b": "1"}); default: all."""
        self.cpus = cpus or {}
        tag = f"{os.getpid() % 10000}{random.randint(0, 99)}"
        self.names = {"a": f"sgsa{tag}", "b": f"sgsb{tag}"}
        self.subnet = random.randint(1, 250)
        self.procs: list[subprocess.Popen] = []
        self.shm: dict[str, str] = {}  # host -> the tmpfs its processes see as /dev/shm

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
        for host in self.names:
            self.shm[host] = tempfile.mkdtemp(prefix=f"sgs-host-{host}-shm-")
            subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1g", "tmpfs", self.shm[host]], check=True)
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
        """Start ``argv`` on ``host``, with the host's /dev/shm (shared by its processes, not the other host's)."""
        shell = f'mount --bind {self.shm[host]} /dev/shm && exec "$@"'
        cmd = ["ip", "netns", "exec", self.names[host], "unshare", "--mount", "--propagation", "private"]
        if host in self.cpus:
            cmd = ["taskset", "-c", self.cpus[host], *cmd]
        cmd += ["sh", "-c", shell, "sh", *argv]
        proc = subprocess.Popen(cmd, env=env, **kwargs)
        self.procs.append(proc)
        return proc

    def bytes_sent(self) -> dict[str, int]:
        """Bytes each host has sent over its end of the veth pair so far (the kernel's counter)."""
        sent = {}
        for host, name in self.names.items():
            out = subprocess.run(
                ["ip", "-n", name, "-s", "-j", "link", "show", "dev", f"v{name}"],
                check=True,
                capture_output=True,
                text=True,
            ).stdout
            sent[host] = int(json.loads(out)[0]["stats64"]["tx"]["bytes"])
        return sent

    def __exit__(self, *exc: object) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=30)
        for name in self.names.values():
            subprocess.run(["ip", "netns", "del", name], capture_output=True, check=False)
        for folder in self.shm.values():
            subprocess.run(["umount", folder], capture_output=True, check=False)
            shutil.rmtree(folder, ignore_errors=True)


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


def _ros_args(params: list[str], remaps: list[str]) -> list[str]:
    return ["--ros-args", *(a for p in params for a in ("-p", p)), *(a for r in remaps for a in ("-r", r))]


def _start(hosts: TwoHosts, host: str, module: str, args: list[str], env: dict[str, str]) -> subprocess.Popen:
    """``python -m module args`` on ``host``, its output kept."""
    argv = [sys.executable, "-m", module, *args]
    return hosts.popen(host, argv, env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _stop(proc: subprocess.Popen) -> str:
    """SIGINT (to ``ip netns exec``, which passes it on: exec all the way down); the output."""
    proc.send_signal(signal.SIGINT)
    return proc.communicate(timeout=120)[0]


def play_across(
    hosts: TwoHosts,
    bag: Path,
    node_params: list[str],
    remaps: list[str],
    timeout_s: float = 300.0,
    profile: Path | None = None,
    split: bool = False,
    poses_out: Path | None = None,
) -> dict[str, float]:
    """``bag_player`` on host a into ``slam_node`` on host b; the node's final counts and the frames sent (``sent``).

    ``split``: instead ``tracking_node`` on host a (beside the player, forwarding the frames it
    accepts) and ``mapping_node`` on host b (mapping them, sending its map back); the counts are the
    tracker's, with the mapper's as ``mapper_frames_in`` and ``mapper_frames_mapped``.
    ``poses_out``: the published poses are recorded on host a into this JSON file. The bytes each
    host sent over the veth pair are ``bytes_a_to_b`` and ``bytes_b_to_a``.
    """
    env = host_env(profile)
    save = "save_on_shutdown:=false"
    recorder = _start(hosts, "a", "bench.pose_recorder", [str(poses_out)], env) if poses_out else None
    if split:
        mapper_params = [*node_params, save, "pose_source:=topic", "frame_source:=tracking_node"]
        mapper = _start(hosts, "b", "sgs_slam_ros.mapping_node", _ros_args(mapper_params, []), env)
        tracker_params = [*node_params, "map_source:=topic", "forward_frames:=true"]
        node = _start(hosts, "a", "sgs_slam_ros.tracking_node", _ros_args(tracker_params, remaps), env)
    else:
        mapper, node = None, _start(hosts, "b", "sgs_slam_ros.slam_node", _ros_args([*node_params, save], remaps), env)
    if recorder is not None and recorder.stdout.readline().strip() != "recording":  # matched to the poses
        raise RuntimeError(f"the pose recorder did not start: {_stop(recorder)}")
    player = _start(hosts, "a", "sgs_slam_ros.bag_player", [str(bag), "--wait", "120"], env)
    before = hosts.bytes_sent()
    player_log = player.communicate(timeout=timeout_s)[0]
    time.sleep(3.0)  # the last frames' callbacks
    after = hosts.bytes_sent()
    counts = final_counts(_stop(node), player_log)
    if mapper is not None:
        mapped = final_counts(_stop(mapper), player_log)
        counts["mapper_frames_in"], counts["mapper_frames_mapped"] = mapped["frames_in"], mapped["frames_mapped"]
    if recorder is not None:
        _stop(recorder)
    counts["bytes_a_to_b"] = after["a"] - before["a"]
    counts["bytes_b_to_a"] = after["b"] - before["b"]
    return counts


def _row(run: int, mode: str, c: dict[str, float], ate_cm: float | None, posed: int, seconds: float) -> list[object]:
    """One table row: frames across, tracked and their ATE, the mapper's share, bytes each way."""
    lost = c["sent"] - c["frames_in"]
    mapper = f"{c['mapper_frames_in']:.0f} / {c['mapper_frames_mapped']:.0f}" if "mapper_frames_in" in c else "-"
    a_to_b, b_to_a = c["bytes_a_to_b"] / 1e6, c["bytes_b_to_a"] / 1e6
    return [
        run,
        mode,
        c["sent"],
        c["frames_in"],
        f"{100 * lost / max(c['sent'], 1):.1f} %",
        c["frames_tracked"],
        c.get("tracking_failures", "-"),
        posed,
        "n/a" if ate_cm is None else f"{ate_cm:.2f}",
        mapper,
        f"{a_to_b:.1f}",
        f"{b_to_a:.1f}",
        f"{(a_to_b + b_to_a) / seconds:.2f}",
    ]


def _run(bag: Path, args: argparse.Namespace, split: bool, work: Path) -> tuple[dict[str, float], dict[int, object]]:
    """One play of ``bag`` across the hosts; the counts and the poses recorded on host a."""
    params = [f"preset:={args.preset}", f"downscale:={args.downscale}", "use_semantics:=false"]
    params.append("map_alignment:=optical")  # the ground truth's convention (ATE aligns anyway)
    params.append(f"gaussians_rate_hz:={args.gaussians_rate_hz}")
    out = work / "poses.json"
    out.unlink(missing_ok=True)
    with TwoHosts({"a": "0", "b": "1"} if args.pin else None) as hosts:
        counts = play_across(hosts, bag, params, REMAPS, profile=args.profile, split=split, poses_out=out)
    poses = {int(k): np.asarray(v) for k, v in json.loads(out.read_text()).items()} if out.exists() else {}
    return counts, poses


def main() -> int:
    from bench.bench_ros_live import published_ate_cm  # noqa: PLC0415 - only for the benchmark
    from bench.common import append_section, markdown_table  # noqa: PLC0415
    from sgs_slam_core.datasets import open_dataset  # noqa: PLC0415

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("input", type=Path, help="a TUM/ScanNet folder (converted to a bag at full size) or a bag")
    p.add_argument("--downscale", type=float, default=4.0, help="the nodes' processing size")
    p.add_argument("--preset", default="tum")
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--split", action="store_true", help="each run also as tracking_node (a) + mapping_node (b)")
    p.add_argument("--pin", action="store_true", help="each host on a CPU core of its own (two 1-core computers)")
    p.add_argument("--gaussians-rate-hz", type=float, default=0.5, help="mapping_node's map publications")
    p.add_argument("--profile", type=Path, help="a Fast DDS profile for both hosts (default: the shipped one)")
    p.add_argument("--no-append", action="store_true")
    args = p.parse_args()
    why = unavailable()
    if why is not None:
        print(f"two_hosts: {why}", file=sys.stderr)
        return 1
    work = Path(tempfile.mkdtemp(prefix="two-hosts-"))
    try:
        bag = _bag(args.input, work)
        stamps = open_dataset(bag).stamps_ns
        seconds = (stamps[-1] - stamps[0]) / 1e9
        rows = []
        for r in range(args.repeats):
            for split in (False, True) if args.split else (False,):
                counts, poses = _run(bag, args, split, work)
                mode = "tracking_node (a) + mapping_node (b)" if split else "slam_node (b)"
                rows.append(_row(r + 1, mode, counts, published_ate_cm(bag, poses), len(poses), seconds))
                print(rows[-1], flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    header = ["run", "nodes", "frames sent", "frames_in", "lost", "tracked", "failed", "posed", "ATE cm"]
    header.append("mapper in / mapped")
    table = markdown_table([*header, "MB a->b", "MB b->a", "MB/s"], rows)
    cpus = "each host on a CPU core of its own" if args.pin else "both hosts on every core"
    body = (
        f"`{args.input.name}` at its recorded size and rate from `bag_player` on host a into the SLAM "
        f"(downscale {args.downscale:g}, semantics off, `gaussians_rate_hz:={args.gaussians_rate_hz:g}`): two "
        f"network namespaces joined by a veth pair, each with its own /dev/shm, {cpus}; Fast DDS profile: "
        f"{args.profile or 'the shipped one'}. MB/s over the recording's {seconds:.1f} s.\n\n{table}\n"
    )
    print(body)
    if not args.no_append:
        append_section("Two hosts: frames across the network", body)
    return 0


def _bag(source: Path, work: Path) -> Path:
    """``source`` as an uncompressed bag (converted at full size when it is a dataset folder)."""
    from bags.format import is_bag  # noqa: PLC0415

    if is_bag(source):
        return source
    bag = work / "bag"
    cmd = [sys.executable, "-m", "bags.cli", "convert", str(source), "--out", str(bag), "--compress", "none"]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    return bag


REMAPS = [
    "rgb/image:=/camera/color/image_raw",
    "depth/image:=/camera/depth/image_raw",
    "rgb/camera_info:=/camera/color/camera_info",
]

if __name__ == "__main__":
    raise SystemExit(main())
