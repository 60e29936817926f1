"""``--viewer rerun|foxglove``: the live stream is produced (recorded to files and read back), not only started."""

import json
import logging
import socket
import subprocess
import sys
import urllib.request
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from sgs_slam_core.cli import main
from sgs_slam_core.config import load_config
from sgs_slam_core.datasets import DatasetOptions, open_dataset
from sgs_slam_core.errors import BackendUnavailableError, ConfigError
from sgs_slam_core.runner import run_offline
from sgs_slam_core.viz import ViewerOptions, ViewerSettings, open_viewer
from sgs_slam_core.viz.viewer import StreamingViewer

pytestmark = pytest.mark.slow  # end to end: left out of make test-fast

rerun_chunk = pytest.importorskip("rerun.chunk", reason="rerun-sdk (extra 'viewer') is not installed")
pytest.importorskip("foxglove", reason="foxglove-sdk (extra 'viewer') is not installed")

QUICK = ("tracking.adam.iterations=3", "mapping.iterations=3", "device=cpu")
FRAMES = 3


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def listening(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def rrd_rows(path) -> dict[str, list[dict]]:
    """Temporal rows per entity path of a .rrd recording."""
    rows = defaultdict(list)
    for chunk in rerun_chunk.RrdReader(str(path)).stream():
        if not chunk.is_static:
            rows[chunk.entity_path] += chunk.to_record_batch().to_pylist()
    for entity in rows:
        rows[entity].sort(key=lambda r: r["frame"])
    return rows


@pytest.fixture(scope="module")
def foxglove_run(tiny_scene, tmp_path_factory):
    """A 3-frame run streamed to Foxglove: live server on a free port plus an MCAP recording."""
    out = tmp_path_factory.mktemp("fox")
    dataset = open_dataset(tiny_scene, options=DatasetOptions(max_frames=FRAMES))
    port = free_port()
    viewer = open_viewer(
        ViewerOptions(
            "foxglove", live=True, save=out / "run" / "live.mcap", port=port, settings=ViewerSettings(points_every=2)
        )
    )
    seen_live = []
    original = viewer.log_step

    def log_step(frame, step, slam):
        seen_live.append(listening(port))  # the server accepts connections while the run goes on
        original(frame, step, slam)

    viewer.log_step = log_step
    result = run_offline(
        dataset,
        load_config("synthetic", overrides=QUICK),
        out / "run",
        show_progress=False,
        render_examples=0,
        viewer=viewer,
    )
    return result, dataset, out / "run" / "live.mcap", seen_live, port


def test_cli_records_the_rerun_stream_inside_the_run_folder(tiny_scene, tmp_path):
    out = tmp_path / "run"
    rrd = out / "live.rrd"  # inside the run folder, which the run creates after the viewer is opened
    sets = [a for o in QUICK for a in ("--set", o)]
    args = [
        "run",
        str(tiny_scene),
        "--out",
        str(out),
        "--max-frames",
        str(FRAMES),
        "--quiet",
        "--viewer-save",
        str(rrd),
        "--viewer-points-every",
        "2",
        *sets,
    ]
    assert main(args) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    rows = rrd_rows(rrd)
    for entity in (
        "/world/camera",
        "/world/camera/input/rgb",
        "/world/camera/input/depth",
        "/world/camera/input/labels",
        "/render/color",
        "/render/depth",
        "/render/semantic",
        "/world/trajectory",
        "/world/ground_truth",
        "/stats/gaussians",
    ):
        assert [r["frame"] for r in rows[entity]] == list(range(FRAMES)), entity
    strips = [r["LineStrips3D:strips"][0] for r in rows["/world/trajectory"]]
    assert [len(s) for s in strips] == [1, 2, 3]  # the camera path grows by one centre per frame
    from sgs_slam_core.metrics import read_tum_trajectory

    _, poses = read_tum_trajectory(out / "trajectory.txt")
    assert np.allclose(strips[-1], poses[:, :3, 3], atol=1e-5)
    gaussians = [r["Scalars:scalars"][0] for r in rows["/stats/gaussians"]]
    assert gaussians[-1] == metrics["num_gaussians"] and gaussians == sorted(gaussians)
    maps = rows["/world/map"]
    assert [r["frame"] for r in maps] == [0, 2]  # every second frame; the last frame carried the map
    assert 0 < len(maps[-1]["Points3D:positions"]) <= metrics["num_gaussians"]
    assert len(maps[-1]["Points3D:class_ids"]) == len(maps[-1]["Points3D:positions"])
    rgb = rows["/world/camera/input/rgb"][0]
    assert rgb["Image:format"][0]["width"] == 64 and rgb["Image:format"][0]["height"] == 48


def test_foxglove_stream_is_served_live_and_recorded(foxglove_run):
    from mcap.reader import make_reader

    result, _, mcap_path, seen_live, port = foxglove_run
    assert seen_live == [True] * FRAMES and not listening(port)  # served during the run, stopped after it
    counts, status, clouds = defaultdict(int), [], []
    with mcap_path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        for _, channel, message in reader.iter_messages():
            counts[channel.topic] += 1
            if channel.topic == "/slam/status":
                status.append(json.loads(message.data))
            if channel.topic == "/map/points":
                clouds.append(message)
    assert schemas["/tf"] == "foxglove.FrameTransforms" and schemas["/map/points"] == "foxglove.PointCloud"
    assert schemas["/camera/image"] == schemas["/render/semantic"] == "foxglove.RawImage"
    for topic in (
        "/tf",
        "/camera/image",
        "/camera/depth",
        "/camera/labels",
        "/camera/calibration",
        "/render/color",
        "/render/depth",
        "/render/semantic",
        "/slam/paths",
        "/slam/status",
    ):
        assert counts[topic] == FRAMES, topic
    assert [s["frame"] for s in status] == [0, 1, 2]
    assert [s["gaussians"] for s in status] == [s.num_gaussians for s in result.steps]
    assert [m.log_time for m in clouds] == [result.steps[0].stamp_ns, result.steps[2].stamp_ns]
    assert len(clouds[-1].data) > 18 * 100  # 18-byte points: x y z (f32), rgba (u8), label (u16)


def test_rerun_serves_a_web_viewer_without_a_display(foxglove_run, monkeypatch):
    result, dataset, *_ = foxglove_run
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    grpc, web = free_port(), free_port()
    viewer = open_viewer(ViewerOptions("rerun", live=True, port=grpc, web_port=web))
    assert any(f"http://127.0.0.1:{web}" in line and "rerun --connect" in line for line in viewer.where)
    viewer.log_step(dataset[0], result.steps[0], result.slam)
    try:
        assert viewer.steps == 1 and listening(grpc)
        with urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=10) as page:
            assert page.status == 200
    finally:
        viewer.close()
    with pytest.raises(BackendUnavailableError, match=f"127.0.0.1:{web}"):  # the web viewer keeps its port
        open_viewer(ViewerOptions("rerun", live=True, port=free_port(), web_port=web))


class Failing(StreamingViewer):
    def __init__(self):
        super().__init__(ViewerOptions("rerun", live=False, save=Path("unused.rrd")))  # never opened
        self.sent, self.finished = 0, 0

    def start(self, table):
        pass

    def send(self, snap):
        if self.sent == 1:
            raise RuntimeError("connection lost")
        self.sent += 1

    def send_points(self, index, stamp_ns, points):
        raise AssertionError("a failed viewer sends nothing more")

    def finish(self):
        self.finished += 1


def test_a_failing_viewer_is_switched_off_and_never_stops_the_run(foxglove_run, caplog):
    result, dataset, *_ = foxglove_run
    viewer = Failing()
    with caplog.at_level(logging.WARNING):
        for i, step in enumerate(result.steps):
            viewer.log_step(dataset[i], step, result.slam)  # raises nothing
    viewer.close()
    viewer.close()
    assert viewer.steps == 1 and viewer.finished == 1
    assert "rerun viewer stopped after 1 frames: connection lost" in caplog.text


def test_bad_viewer_options_are_config_errors(monkeypatch):
    with pytest.raises(ConfigError, match=r"records to a \.mcap file"):
        ViewerOptions("foxglove", save=Path("x.rrd"))
    with pytest.raises(ConfigError, match="live view or a file"):
        ViewerOptions("rerun", live=False)
    monkeypatch.setattr("sgs_slam_core.viz.viewer.importlib.util.find_spec", lambda name: None)
    with pytest.raises(BackendUnavailableError, match=r"pip install 'sgs_slam_ros\[viewer\]'"):
        open_viewer(ViewerOptions("foxglove"))


def test_importing_the_viz_package_loads_no_viewer_backend():
    code = "import sgs_slam_core.viz, sys; print(sorted(m for m in ('rerun', 'foxglove') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
