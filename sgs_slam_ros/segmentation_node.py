"""``segmentation_node``: a label source for live cameras (optional extra: ``sgs_slam_ros[segmentation]``).

Subscribes ``rgb/image`` (remappable, the colour camera) and publishes ``semantic/image``: 16UC1
NYU40 class ids with the colour image's stamp and frame id, the topic the SLAM nodes read, so the
same ``rgb/image`` remap serves both; and ``semantic/label_table`` (std_msgs/String, JSON of the
label table, latched) naming what the ids mean. The model is SegFormer trained on ADE20K
(``model``: a Hugging Face hub name or a saved folder), its classes mapped to NYU40
(:mod:`sgs_slam_core.segmentation.ade20k`). The newest image is segmented when the model is free;
older ones are dropped and counted; ``max_rate_hz`` caps the rate. ``/diagnostics``: rates, counts,
the model and its device.
"""

from __future__ import annotations

import json
import threading
import time

import torch
from rclpy.node import Node
from sensor_msgs.msg import Image
from std_msgs.msg import String

from msg_adapters import AdapterError, rgb_from_image, stamp_to_ns
from sgs_slam_core.errors import SgsSlamError
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.segmentation import DEFAULT_MODEL, Segmenter
from sgs_slam_core.slam.system import resolve_device
from sgs_slam_ros.diagnostics import OK, WARN, Diagnostics, RateMeter
from sgs_slam_ros.messages import image_msg
from sgs_slam_ros.params import ParamSpec, declare
from sgs_slam_ros.qos import INPUT_QOS_CHOICES, input_qos, latched_qos, output_qos
from sgs_slam_ros.runtime import run_nodes

__all__ = ["SEGMENTATION", "SegmentationNode", "main"]

SEGMENTATION = (
    ParamSpec(
        "model", DEFAULT_MODEL, "SegFormer ADE20K model: Hugging Face hub name or a saved folder", read_only=True
    ),
    ParamSpec("device", "auto", "compute device", choices=("auto", "cpu", "cuda"), read_only=True),
    ParamSpec("input_qos", "best_effort", "image subscription QoS", choices=INPUT_QOS_CHOICES, read_only=True),
    ParamSpec("input_queue_size", 30, "messages the image subscription holds", bounds=(1, 1000), read_only=True),
    ParamSpec(
        "downscale",
        1.0,
        "the model sees the colour image this many times smaller (labels still at its size): 2 takes a third "
        "of the time of 640x480",
        bounds=(1.0, 16.0),
        read_only=True,
    ),
    ParamSpec(
        "threads",
        0,
        "torch CPU threads of this process (0 = torch's default); 1 leaves a small CPU's other cores to the SLAM",
        bounds=(0, 256),
        read_only=True,
    ),
    ParamSpec(
        "max_rate_hz",
        0.0,
        "segment at most this many images a second (0 = as fast as the model runs); on a small CPU a cap leaves "
        "the SLAM its share of the cores",
        bounds=(0.0, 1000.0),
        read_only=True,
    ),
)


class SegmentationNode(Node):
    """Segments the newest colour image on a worker thread and publishes its class ids."""

    def __init__(self, segmenter: Segmenter | None = None, **kwargs: object) -> None:
        """``segmenter``: use this model instead of loading ``model`` (tests, composition)."""
        super().__init__("segmentation_node", **kwargs)
        self.params = declare(self, SEGMENTATION)
        if self.params["threads"] > 0:  # process-wide: set before the model runs
            torch.set_num_threads(self.params["threads"])
        if segmenter is None:
            segmenter = Segmenter.from_pretrained(self.params["model"], resolve_device(self.params["device"]))
        self.segmenter = segmenter
        self.table = LabelTable.nyu40()
        qos = input_qos(self.params["input_qos"], self.params["input_queue_size"])
        self.create_subscription(Image, "rgb/image", self._on_image, qos)
        self.labels_pub = self.create_publisher(Image, "semantic/image", output_qos(5))
        self.table_pub = self.create_publisher(String, "semantic/label_table", latched_qos())
        self.table_pub.publish(String(data=json.dumps(self.table.to_dict(), separators=(",", ":"))))
        self.frames_in = self.segmented = self.dropped = self.rejected = 0
        self.inputs, self.outputs = RateMeter(), RateMeter()
        self.last_ms = 0.0
        self.last_error = ""
        self._newest: Image | None = None
        self._cv = threading.Condition()
        self._running = True
        self._worker = threading.Thread(target=self._loop, name="segmentation", daemon=True)
        self._worker.start()
        self.diagnostics = Diagnostics(self, self._status)
        self.get_logger().info(
            f"segmenting {self.resolve_topic_name('rgb/image')} with {segmenter.name} on {segmenter.device} into "
            f"{self.resolve_topic_name('semantic/image')} (NYU40 ids; table on "
            f"{self.resolve_topic_name('semantic/label_table')})"
        )

    def _on_image(self, msg: Image) -> None:
        self.inputs.tick()
        with self._cv:
            self.frames_in += 1
            self.dropped += int(self._newest is not None)  # the model was busy or capped: the older image goes
            self._newest = msg
            self._cv.notify()

    def _loop(self) -> None:
        period = 1.0 / self.params["max_rate_hz"] if self.params["max_rate_hz"] > 0 else 0.0
        next_start = time.monotonic()
        while True:
            with self._cv:
                # the rate cap first (a stop ends it at once), then the newest image: the freshest is segmented
                self._cv.wait_for(lambda: not self._running, timeout=max(0.0, next_start - time.monotonic()))
                self._cv.wait_for(lambda: self._newest is not None or not self._running)
                if not self._running:
                    return
                msg, self._newest = self._newest, None
            next_start = time.monotonic() + period
            self._segment(msg)

    def _segment(self, msg: Image) -> None:
        try:
            rgb = rgb_from_image(msg)
            t0 = time.perf_counter()
            labels = self.segmenter(rgb, self.params["downscale"])
            self.last_ms = 1e3 * (time.perf_counter() - t0)
        except (AdapterError, SgsSlamError) as err:
            self.rejected += 1
            if not self.last_error:
                self.get_logger().warn(f"dropping input: {err} (counted in /diagnostics, logged once)")
            self.last_error = str(err)
            return
        if not self.context.ok():
            return
        self.labels_pub.publish(image_msg(labels, "16UC1", stamp_to_ns(msg.header.stamp), msg.header.frame_id))
        self.segmented += 1
        self.outputs.tick()

    def _status(self) -> tuple[int, str, dict[str, str]]:
        idle = self.inputs.idle_s()
        level, message = OK, "segmenting"
        if idle is None or idle > 5.0:
            level, message = (
                WARN,
                f"no colour image on {self.resolve_topic_name('rgb/image')} "
                + ("yet" if idle is None else f"for {idle:.0f} s"),
            )
        values = {
            "model": self.segmenter.name,
            "device": str(self.segmenter.device),
            "input_rate_hz": f"{self.inputs.rate():.2f}",
            "processing_rate_hz": f"{self.outputs.rate():.2f}",
            "last_frame_ms": f"{self.last_ms:.0f}",
            "model_input": f"1/{self.params['downscale']:g} of the colour image, {torch.get_num_threads()} threads",
            "max_rate_hz": f"{self.params['max_rate_hz']:g}" if self.params["max_rate_hz"] > 0 else "none",
            "frames_in": str(self.frames_in),
            "frames_segmented": str(self.segmented),
            "frames_dropped": str(self.dropped),
            "frames_rejected": str(self.rejected),
            "label_table": f"{self.table.name} ({len(self.table)} classes)",
        }
        return level, message, values

    def close(self) -> None:
        """Stop the worker and log what became of the colour images."""
        with self._cv:
            self._running = False
            self._cv.notify()
        self._worker.join(timeout=30.0)
        self.get_logger().info(
            f"final counts: frames_in {self.frames_in}, frames_segmented {self.segmented}, "
            f"frames_dropped {self.dropped}, frames_rejected {self.rejected}"
        )


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run sgs_slam_ros segmentation_node``."""
    return run_nodes(lambda: [SegmentationNode()], args)


if __name__ == "__main__":
    raise SystemExit(main())
