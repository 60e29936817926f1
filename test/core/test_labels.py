import numpy as np
import pytest
import torch

from sgs_slam_core.errors import FrameError, ShapeError
from sgs_slam_core.labels import LabelClass, LabelError, LabelTable, palette_color
from sgs_slam_core.semantics import SemanticCodec, SemanticSettings


def test_nyu40_table():
    t = LabelTable.nyu40()
    assert len(t) == 41
    assert t.name_of(1) == "wall" and t.color_of(1) == (174, 199, 232)
    assert t.name_of(5) == "chair" and t.color_of(5) == (188, 189, 34)
    assert t.id_of("otherprop") == 40 and t.id_of("7") == 7
    assert t.color_of(0) == (0, 0, 0)
    with pytest.raises(LabelError, match="unknown class name 'unicorn'"):
        t.id_of("unicorn")


def test_palette_is_deterministic_and_distinct():
    colors = [palette_color(i) for i in range(256)]
    assert colors[0] == (0, 0, 0) and colors[1] == (128, 0, 0)
    assert len(set(colors)) == 256
    assert palette_color(300) == palette_color(300)
    t = LabelTable.nyu40()
    assert t.color_of(1000) == palette_color(1000)


def test_colorize_and_dict_round_trip():
    t = LabelTable([LabelClass(3, "chair", (1, 2, 3))], name="mine")
    img = t.colorize(np.array([[0, 3], [3, 7]]))
    assert img.dtype == np.uint8 and img.shape == (2, 2, 3)
    assert tuple(img[0, 1]) == (1, 2, 3) and tuple(img[1, 1]) == palette_color(7)
    assert LabelTable.from_dict(t.to_dict()) == t
    assert 7 in t.with_ids([7, 3]) and 7 not in t
    with pytest.raises(LabelError, match=r"0\.\.255"):
        LabelTable([LabelClass(2, "bad", (300, 0, 0))])


@pytest.mark.parametrize("mode", ["color", "onehot"])
def test_codec_round_trip(mode):
    table = LabelTable.nyu40()
    codec = SemanticCodec(SemanticSettings(mode=mode, num_classes=41), table)
    labels = torch.tensor([[0, 1, 5], [40, 7, 7]])
    enc = codec.encode(labels)
    assert enc.shape == (2, 3, codec.num_channels)
    assert torch.equal(codec.encode(labels, (0, 40)), enc)  # the range given from the host: the same targets
    assert codec.encode(labels[:0], (0, 0)).shape == (0, 3, codec.num_channels)
    assert torch.equal(codec.decode(enc), labels)
    noisy = enc + 0.02 * torch.randn(enc.shape, generator=torch.Generator().manual_seed(0))
    assert torch.equal(codec.decode(noisy), labels)


def test_color_encoding_by_palette_matches_the_unique_reference():
    codec = SemanticCodec(SemanticSettings(), LabelTable.nyu40())
    gen = torch.Generator().manual_seed(0)
    for top in (1, 41, 300, 70_000):  # the palette grows; ids past 65535 take the reference path
        labels = torch.randint(0, top, (37, 53), generator=gen)
        assert torch.equal(codec.encode(labels), codec.encode_by_unique(labels))
    with pytest.raises(LabelError, match="class ids"):
        codec.encode(torch.tensor([[-1, 3], [2, 3]]))
    assert codec.encode(torch.zeros((0, 4), dtype=torch.int64)).shape == (0, 4, 3)


def test_codec_candidates_and_errors():
    codec = SemanticCodec(SemanticSettings(mode="onehot", num_classes=4), LabelTable.from_ids(range(4)))
    sem = torch.tensor([[0.1, 0.5, 0.3, 0.1]])
    assert codec.decode(sem).item() == 1
    assert codec.decode(sem, candidates=[0, 2]).item() == 2
    with pytest.raises(FrameError, match="num_classes"):
        codec.encode(torch.tensor([4]))
    with pytest.raises(FrameError, match="class id 4 "):
        codec.encode(torch.tensor([4]), (4, 4))
    with pytest.raises(ShapeError, match="channels"):
        codec.decode(torch.zeros(2, 3))
    color = SemanticCodec(SemanticSettings(), LabelTable.nyu40())
    mid = (color.class_colors([1]) + 0.01).reshape(1, 3)
    assert color.decode(mid, candidates=[1, 2]).item() == 1


def _three_class_codec() -> SemanticCodec:
    """Classes 1 and 2 whose blends are nearer class 3's colour than their own."""
    table = LabelTable(
        [LabelClass(1, "red", (200, 0, 0)), LabelClass(2, "blue", (0, 0, 200)), LabelClass(3, "grey", (100, 100, 100))]
    )
    return SemanticCodec(SemanticSettings(), table)


def test_decode_image_resolves_a_boundary_blend_to_a_class_beside_it_not_a_third_one():
    codec = _three_class_codec()
    labels = torch.tensor([[1, 1, 2, 2]] * 3)  # a vertical boundary between columns 1 and 2
    rendered = codec.encode(labels)
    rendered[:, 1] = 0.6 * rendered[:, 1] + 0.4 * codec.encode(torch.tensor(2))  # blended at the boundary
    rendered[:, 2] = 0.5 * rendered[:, 2] + 0.5 * codec.encode(torch.tensor(1))
    plain = codec.decode(rendered)
    assert (plain[:, 1:3] == 3).all()  # the nearest colour of each blend is the third class
    image = codec.decode_image(rendered)
    assert torch.equal(image[:, 0], plain[:, 0]) and torch.equal(image[:, 3], plain[:, 3])
    assert (image[:, 1] == 1).all() and (image[:, 2] == 2).all()  # the class of the confident neighbour


def test_decode_image_keeps_a_real_third_class_and_isolated_blends():
    codec = _three_class_codec()
    labels = torch.tensor([[1, 3, 3, 2]] * 3)  # class 3 is really there: its pixels are near its colour
    noisy = codec.encode(labels) + 0.01 * torch.randn((3, 4, 3), generator=torch.Generator().manual_seed(0))
    assert torch.equal(codec.decode_image(noisy), labels)
    lone = codec.encode(torch.tensor([[1]])) * 0.5 + codec.encode(torch.tensor([[2]])) * 0.5  # no neighbours
    assert torch.equal(codec.decode_image(lone), codec.decode(lone))


def test_decode_image_is_decode_for_onehot_and_rejects_what_is_no_image():
    codec = SemanticCodec(SemanticSettings(mode="onehot", num_classes=5), LabelTable.nyu40())
    soft = torch.softmax(torch.randn((4, 6, 5), generator=torch.Generator().manual_seed(1)), dim=-1)
    assert torch.equal(codec.decode_image(soft, [1, 2, 4]), codec.decode(soft, [1, 2, 4]))
    with pytest.raises(ShapeError, match=r"\[H, W, S\]"):
        _three_class_codec().decode_image(torch.zeros(5, 3))
