"""Dataset folders <-> rosbag2 MCAP bags, without rclpy (rosbags writer, mcap reader)."""

from bags.errors import BagError
from bags.layout import BagTopics
from bags.reader import BagDataset, open_bag
from bags.writer import ConvertSummary, convert

__all__ = ["BagDataset", "BagError", "BagTopics", "ConvertSummary", "convert", "open_bag"]
