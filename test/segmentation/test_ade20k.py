"""The documented mapping of ADE20K's classes to NYU40 (no model, no optional extra needed)."""

import pytest

from sgs_slam_core.labels import LabelTable
from sgs_slam_core.segmentation import ADE20K_CLASSES, ADE20K_TO_NYU40, ade20k_to_nyu40_lut


def test_every_mapped_class_exists_on_both_sides():
    nyu = LabelTable.nyu40()
    assert len(ADE20K_CLASSES) == len(set(ADE20K_CLASSES)) == 150
    assert set(ADE20K_TO_NYU40) <= set(ADE20K_CLASSES)
    assert all(nyu.id_of(name) > 0 for name in ADE20K_TO_NYU40.values())


@pytest.mark.parametrize(
    ("ade", "nyu"),
    [
        ("wall", "wall"),
        ("floor", "floor"),
        ("armchair", "chair"),
        ("swivel chair", "chair"),
        ("painting", "picture"),
        ("bookcase", "bookshelf"),
        ("television receiver", "television"),
        ("chest of drawers", "dresser"),
        ("windowpane", "window"),
        ("cushion", "pillow"),
        ("stool", "otherfurniture"),
        ("vase", "otherprop"),
    ],
)
def test_indoor_classes_map_by_meaning(ade, nyu):
    assert ade20k_to_nyu40_lut()[ADE20K_CLASSES.index(ade)] == LabelTable.nyu40().id_of(nyu)


def test_outdoor_classes_are_unlabelled():
    lut = ade20k_to_nyu40_lut()
    assert all(lut[ADE20K_CLASSES.index(n)] == 0 for n in ("sky", "road", "car", "tree", "grass", "airplane"))
    assert lut.shape == (150,) and lut.min() == 0 and lut.max() == 40


def test_without_the_extra_the_model_is_one_clear_error(monkeypatch):
    import sys

    from sgs_slam_core.segmentation import SegmentationError, Segmenter

    monkeypatch.setitem(sys.modules, "transformers", None)  # as if the extra were not installed
    with pytest.raises(SegmentationError, match=r"pip install 'sgs_slam_ros\[segmentation\]'"):
        Segmenter.from_pretrained()
