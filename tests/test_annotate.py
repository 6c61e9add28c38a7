"""The annotated video (``track --annotate``): every frame says its status,
in words and colour, and text is drawn on a filled box (readable on any
image)."""

from types import SimpleNamespace

import numpy as np

from mutloc.detect.base import Detection, DetectionResult
from mutloc.track.annotate import draw_pair
from mutloc.track.status import FrameStatus
from mutloc.track.tracker import TrackRow


def _frame(status, reason=""):
    white = np.full((240, 320, 3), 255, np.uint8)
    est = SimpleNamespace(t=np.array([0.1, 0.0, 2.0]), reprojection_rms_px=0.4)
    det = DetectionResult()
    det.detections["M1"] = Detection("M1", np.array([160.0, 120.0]), 1.0)
    row = TrackRow(1.0, 1.0, 1.0, status, reason, est, {"p": det})
    return draw_pair(white, white, row, "p", "q")


def _text_colour(region):
    """Mean colour of the region's saturated pixels (the text, not the box or a white image)."""
    px = region.reshape(-1, 3).astype(int)
    vivid = px[(px.max(axis=1) - px.min(axis=1)) > 80]
    assert len(vivid) > 20
    return vivid.mean(axis=0)


def test_each_frame_shows_its_status_in_words_and_colour():
    solved, predicted = _frame(FrameStatus.SOLVED), _frame(FrameStatus.PREDICTED, "no markers")
    bottom = slice(240 - 30, 240)
    assert solved.shape == predicted.shape == (240, 640, 3)
    assert not np.array_equal(solved[bottom], predicted[bottom])  # the status line differs
    assert np.abs(_text_colour(solved[bottom]) - _text_colour(predicted[bottom])).max() > 60
    assert not np.array_equal(predicted[240 - 60:240 - 30], solved[240 - 60:240 - 30])  # the reason, above it


def test_text_is_drawn_on_a_filled_box():
    """On a white image the status line and the labels sit on a dark box:
    most pixels behind the text are dark, not the image's white."""
    frame = _frame(FrameStatus.SOLVED)
    status_box = frame[240 - 24:240 - 6, 12:200]
    assert (status_box.max(axis=-1) < 100).mean() > 0.5
    name_box = frame[95:108, 172:190]  # "M1" next to its detection at (160, 120)
    assert (name_box.max(axis=-1) < 100).mean() > 0.3
