"""The label-noise model: each kind of mistake does what it says, reproducibly, and runs score against the truth."""

import itertools
import json

import numpy as np
import pytest

from sgs_slam_core.cli import main
from sgs_slam_core.datasets import open_dataset
from sgs_slam_core.datasets.label_noise import (
    LABEL_NOISE_LEVELS,
    LabelNoise,
    NoisyLabels,
    confusion_partners,
    degrade_labels,
)
from sgs_slam_core.errors import ConfigError
from sgs_slam_core.metrics import ConfusionMatrix

from ..conftest import FAST_SLAM

pytestmark = pytest.mark.slow  # end to end: left out of make test-fast


def halves() -> np.ndarray:  # [20, 40]: class 3 on the left, 7 on the right, one class-5 square inside the left
    labels = np.full((20, 40), 3, np.int32)
    labels[:, 20:] = 7
    labels[5:10, 5:10] = 5
    return labels


def test_flicker_turns_whole_regions_into_another_class_of_the_frame():
    labels = halves()
    out = degrade_labels(labels, LabelNoise(flicker=1.0), {}, np.random.default_rng(0))
    for c in (3, 5, 7):
        region = out[labels == c]
        assert np.unique(region).size == 1  # a region changes as a whole
        assert region[0] != c and region[0] in (3, 5, 7)  # to another class present in the frame


def test_confusion_turns_a_region_into_its_class_partner_and_partners_are_fixed_by_the_seed():
    partners = confusion_partners([0, 3, 5, 7], seed=4)
    assert partners == confusion_partners([0, 3, 5, 7], seed=4) and set(partners) == {3, 5, 7}
    assert all(p != c and p in (3, 5, 7) for c, p in partners.items())
    labels = halves()
    out = degrade_labels(labels, LabelNoise(confusion=1.0), partners, np.random.default_rng(1))
    for c in (3, 5, 7):
        assert np.all(out[labels == c] == partners[c])


def test_bleeding_moves_boundaries_by_its_pixels_and_leaves_the_inside_alone():
    labels = halves()
    out = degrade_labels(labels, LabelNoise(bleed_px=2), {}, np.random.default_rng(2))
    changed = np.argwhere(out != labels)
    assert changed.size  # some class grew over a neighbour
    left, right = labels[:, :20] == 3, labels[:, 20:] == 7
    # the vertical boundary between 3 and 7 (x = 19 | 20) moved by exactly 2 px one way or the other
    moved = (out[12:, 18:20] == 7).all() or (out[12:, 20:22] == 3).all()
    assert moved and left.any() and right.any()
    assert np.all(changed[:, 1] >= 2) and np.all(out[:, :2][labels[:, :2] == 3] == 3)  # far from boundaries: kept
    assert set(np.unique(out)) <= {3, 5, 7}  # bleeding invents no class


def test_classes_bleed_into_unlabelled_pixels_but_unlabelled_never_grows():
    labels = halves()
    labels[:, 30:] = 0
    out = degrade_labels(labels, LabelNoise(bleed_px=3), {}, np.random.default_rng(3))
    assert np.all(out[:, 30:33] == 7) and np.all(out[:, 33:] == 0)  # 3 px of the class over the unlabelled
    assert np.all(out[labels > 0] > 0)


def test_levels_are_ordered_and_settings_are_checked():
    tiers = [LABEL_NOISE_LEVELS[n] for n in ("low", "middle", "high")]
    for a, b in itertools.pairwise(tiers):
        assert a.unlabelled <= b.unlabelled and a.flicker <= b.flicker and a.bleed_px <= b.bleed_px
    with pytest.raises(ConfigError, match="flicker"):
        LabelNoise(flicker=1.5)
    with pytest.raises(ConfigError, match="bleed_px"):
        LabelNoise(bleed_px=-1)


def test_noisy_dataset_is_reproducible_keeps_the_truth_and_drops_label_images(tiny_scene):
    truth = open_dataset(tiny_scene)
    noisy = NoisyLabels(truth, LABEL_NOISE_LEVELS["high"], seed=3)
    again = NoisyLabels(truth, LABEL_NOISE_LEVELS["high"], seed=3)
    frames = [noisy[i] for i in reversed(range(len(truth)))][::-1]  # read backwards: the same images
    for i, f in enumerate(frames):
        g = again[i]
        assert (f.labels is None) == (g.labels is None)
        if f.labels is not None:
            assert np.array_equal(f.labels, g.labels)
        assert np.array_equal(f.rgb, truth[i].rgb) and f.stamp_ns == truth[i].stamp_ns
    dropped = NoisyLabels(truth, LabelNoise(unlabelled=1.0))
    assert all(dropped[i].labels is None for i in range(len(truth)))
    cm = ConfusionMatrix()
    for i, f in enumerate(frames):
        if f.labels is not None:
            cm.update(f.labels, truth[i].labels)
    assert cm.miou() < 1.0  # the noise is there


def test_run_with_label_noise_scores_the_map_and_the_input_against_the_truth(tiny_scene, tmp_path, capsys):
    sets = [a for o in FAST_SLAM for a in ("--set", o)]
    clean, noisy = tmp_path / "clean", tmp_path / "noisy"
    assert main(["run", str(tiny_scene), "--out", str(clean), "--quiet", *sets]) == 0
    assert main(["run", str(tiny_scene), "--out", str(noisy), "--quiet", "--label-noise", "high", *sets]) == 0
    m_clean = json.loads((clean / "metrics.json").read_text())
    m_noisy = json.loads((noisy / "metrics.json").read_text())
    assert m_clean.get("input_miou") is None
    assert 0.0 < m_noisy["input_miou"] < 1.0
    assert m_noisy["miou"] < m_clean["miou"]  # scored against the truth, not against what it was fed
    assert "label images fed in" in capsys.readouterr().out
    assert main(["eval", str(noisy), "--no-write"]) == 0  # re-evaluated against the truth, the input's score kept
    assert f"{100 * m_noisy['input_miou']:.2f}" in capsys.readouterr().out


def test_label_noise_on_a_dataset_without_labels_is_one_line(tmp_path, capsys):
    from sgs_slam_core.synthetic import generate, preset_config

    scene = generate(tmp_path / "scene", preset_config("tiny"))
    for f in (scene / "semantic_ids").glob("*"):
        f.unlink()
    (scene / "semantic_ids").rmdir()
    assert main(["run", str(scene), "--out", str(tmp_path / "r"), "--label-noise", "low"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--label-noise needs a dataset with label images" in err[0]
