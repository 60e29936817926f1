import numpy as np
import pytest

from sgs_slam_core.errors import FrameError
from sgs_slam_core.frame import Frame
from sgs_slam_core.geometry import Intrinsics

K = Intrinsics(50.0, 50.0, 7.5, 5.5, 16, 12)


def frame(**kw):
    args = {"rgb": np.zeros((12, 16, 3), np.uint8), "depth": np.ones((12, 16), np.float32), "intrinsics": K}
    args.update(kw)
    return Frame(**args)


def test_valid_frame():
    f = frame(labels=np.zeros((12, 16), np.int32), gt_c2w=np.eye(4))
    assert f.has_labels and f.valid_depth_fraction == 1.0


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"rgb": np.zeros((12, 16, 3), np.float32)}, "rgb must be uint8"),
        ({"depth": np.ones((10, 16), np.float32)}, "depth must be"),
        ({"depth": np.ones((12, 16), np.uint16)}, "float32 metres"),
        ({"depth": np.full((12, 16), np.nan, np.float32)}, "NaN"),
        ({"depth": -np.ones((12, 16), np.float32)}, "negative"),
        ({"labels": np.zeros((12, 15), np.int32)}, "labels must be"),
        ({"labels": np.zeros((12, 16), np.float32)}, "integer class ids"),
        ({"gt_c2w": np.full((4, 4), np.inf)}, "not finite"),
    ],
)
def test_bad_frames_raise_frame_error(kw, match):
    with pytest.raises(FrameError, match=match):
        frame(**kw)
