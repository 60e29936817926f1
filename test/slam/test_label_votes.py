"""Class votes: a Gaussian's class is what most labelled views say, whatever their order; the map renders it."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from sgs_slam_core.config import load_config
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.datasets.label_noise import LabelNoise, NoisyLabels
from sgs_slam_core.errors import ConfigError
from sgs_slam_core.frame import CompactFrame
from sgs_slam_core.frame_data import FrameTensors
from sgs_slam_core.gaussians import GaussianMap
from sgs_slam_core.geometry.camera import Intrinsics
from sgs_slam_core.labels import LabelTable
from sgs_slam_core.semantics import SemanticCodec, SemanticSettings
from sgs_slam_core.slam.label_votes import cast_votes, seen_classes
from sgs_slam_core.slam.system import Slam

from ..conftest import FAST_SLAM

K = Intrinsics(fx=20.0, fy=20.0, cx=8.0, cy=6.0, width=16, height=12)
CODEC = SemanticCodec(SemanticSettings(), LabelTable.nyu40())


def gaussians(points: list[list[float]], classes: list[int]) -> GaussianMap:
    n = len(points)
    return GaussianMap(
        means=torch.tensor(points),
        log_scales=torch.zeros(n, 1),
        logit_opacities=torch.zeros(n),
        colors=torch.zeros(n, 3),
        semantics=torch.zeros(n, 3),
        labels=torch.tensor(classes, dtype=torch.long),
        birth_frame=torch.zeros(n, dtype=torch.long),
    )


def vote(g: GaussianMap, classes: list[int], locked: list[int] | None = None) -> GaussianMap:
    rows = torch.arange(len(classes))
    ids = None if locked is None else torch.tensor(locked, dtype=torch.long)
    return cast_votes(g, rows, torch.tensor(classes, dtype=torch.long), ids)


def test_the_majority_class_wins_in_any_order():
    for order in ([3, 3, 3, 5, 5], [5, 5, 3, 3, 3], [3, 5, 3, 5, 3], [5, 3, 5, 3, 3]):
        g = gaussians([[0, 0, 1]], [0])
        for c in order:
            g = vote(g, [c])
        assert int(g.labels[0]) == 3, order
        assert float(g.label_weight[0]) >= 1  # the winner keeps a margin


def test_a_few_flickering_views_do_not_move_a_class_many_views_agreed_on():
    g = gaussians([[0, 0, 1]], [0])
    for c in [7] * 6 + [2, 9, 2]:
        g = vote(g, [c])
    assert int(g.labels[0]) == 7 and float(g.label_weight[0]) == 3


def test_locked_classes_neither_gain_nor_lose_gaussians():
    g = gaussians([[0, 0, 1], [0, 0, 1]], [4, 6])
    g = vote(g, [6, 4], locked=[4])  # row 0 is locked (4); row 1 would become locked 4
    assert g.labels.tolist() == [4, 6] and g.label_weight.tolist() == [0, 0]


def test_a_view_votes_only_for_centres_it_sees_at_their_depth_on_labelled_pixels():
    points = [
        [0.0, 0.0, 1.0],  # on the surface: seen
        [0.0, 0.0, 1.5],  # behind the surface (hidden)
        [5.0, 0.0, 1.0],  # outside the image
        [0.0, 0.0, -1.0],  # behind the camera
        [-0.38, 0.0, 1.0],  # on the surface over an unlabelled pixel (u = 0)
    ]
    g = gaussians(points, [0, 0, 0, 0, 0])
    lab = np.full((K.height, K.width), 3, np.int32)
    lab[:, :2] = 0
    data = FrameTensors.from_arrays(0, K, np.zeros((12, 16, 3), np.uint8), np.ones((12, 16), np.float32), lab, CODEC,
                                    torch.device("cpu"))  # fmt: skip
    rows, classes, pixel = seen_classes(g, data, torch.eye(4))
    assert rows.tolist() == [0] and classes.tolist() == [3] and pixel.tolist() == [6 * 16 + 8]


def test_maps_without_votes_load_and_votes_travel_with_their_gaussians():
    g = vote(gaussians([[0, 0, 1], [0, 0, 2], [0, 0, 3]], [0, 0, 0]), [3, 4, 5])
    state = g.state_dict()
    assert torch.equal(GaussianMap.from_state_dict(state).label_weight, g.label_weight)
    del state["label_weight"]  # a map saved before votes existed
    assert GaussianMap.from_state_dict(state).label_weight.tolist() == [0, 0, 0]
    kept = g.select(torch.tensor([False, True, True]))
    assert kept.labels.tolist() == [4, 5] and kept.label_weight.tolist() == [1, 1]
    assert g.cat(gaussians([[1, 1, 1]], [2])).label_weight.tolist() == [1, 1, 1, 0]


def test_fusion_setting_is_checked():
    with pytest.raises(ConfigError, match="fusion"):
        SemanticSettings(fusion="average")


def _class_accuracy(slam: Slam, dataset, frames: list[int]) -> float:
    """Fraction of the map's rendered class pixels equal to the truth, over ``frames``."""
    right = total = 0
    for i in frames:
        f = dataset[i]
        out = slam.render_view(slam.trajectory[i][2])
        decoded = slam.decode(out.semantic).cpu().numpy()
        keep = f.labels > 0
        right += int((decoded[keep] == f.labels[keep]).sum())
        total += int(keep.sum())
    return right / total


def _mapped(fusion: str, dataset, truth) -> Slam:
    slam = Slam(load_config("synthetic", overrides=[*FAST_SLAM, f"semantic.fusion={fusion}"]), truth.label_table)
    for i in range(len(truth)):
        slam.process(dataset[i])
    return slam


def test_votes_make_each_gaussian_the_class_most_views_gave_it_and_render_it(tiny_scene):
    truth = open_dataset(tiny_scene)
    noisy = NoisyLabels(truth, LabelNoise(flicker=0.2), seed=1)  # a fifth of the regions flicker in each frame
    slam = _mapped("votes", noisy, truth)
    g = slam.gaussians
    labelled = g.labels > 0
    assert labelled.float().mean() > 0.9 and (g.label_weight[labelled] >= 1).float().mean() > 0.8
    confident = g.label_weight >= 2  # their features say the voted class; a splat on a boundary keeps its own
    assert confident.float().mean() > 0.5 and torch.equal(slam.decode(g.semantics[confident]), g.labels[confident])
    voted = _class_accuracy(slam, truth, list(range(len(truth))))
    regressed = _class_accuracy(_mapped("regression", noisy, truth), truth, list(range(len(truth))))
    assert voted > 0.9 and voted > regressed + 0.03  # measured 0.94 and 0.86


def test_late_labels_vote_into_the_gaussians_their_view_sees(tiny_scene):
    dataset = open_dataset(tiny_scene)
    config = load_config("synthetic", overrides=[*FAST_SLAM, "semantic.fusion=votes", "mapping.iterations=2"])
    slam = Slam(config, dataset.label_table)
    frames = [dataset[i] for i in range(4)]
    for f in frames:
        slam.process(replace(f, labels=None))
    assert int((slam.gaussians.labels > 0).sum()) == 0
    view = CompactFrame.from_frame(replace(frames[3], labels=None, index=3), np.linalg.inv(slam.trajectory[3][2]))
    slam.fuse_labels(view, frames[3].labels, optimise=False)
    g = slam.gaussians
    voted = g.label_weight > 0
    assert voted.any() and (g.labels[voted] > 0).all()
    # one view: every Gaussian it sees took its class with one vote; those beside its surface took
    # the class of the point they lie by without a vote; no other has one
    assert (g.label_weight[voted] == 1).all()
    beside = (g.labels > 0) & ~voted
    assert (g.label_weight[beside] == 0).all() and int(beside.sum()) < int(voted.sum())
