"""A video written as it goes: MP4 (MPEG-4 Part 2, what OpenCV's ``mp4v``
writes) in fragments of one frame each, flushed to the file as they are
made, so a killed run leaves an MP4 that plays up to its last frames.

OpenCV's ``VideoWriter`` cannot do this: it writes the MP4 index (``moov``)
at the end and keeps the data in FFmpeg's buffer, so a killed run leaves a
file no player opens.  This writer uses PyAV (FFmpeg) with the muxer's
``frag_every_frame+empty_moov`` flags and ``flush_packets``.  A fragment is
closed when the next frame comes: a killed run's video lacks the last frame
written; :meth:`VideoWriter.close` writes it.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np

from .._extras import require
from ..errors import FileFormatError, InputError
from ._files import PathLike, output_folder
from .streaming import StreamWriter

__all__ = ["VideoWriter"]


class VideoWriter(StreamWriter):
    """Streams BGR frames (``uint8``, ``(h, w, 3)``) into a fragmented MP4
    at ``fps`` frames per second; the frame size is the first frame's (odd
    sizes get a black row or column: the codec needs even ones)."""

    def __init__(self, path: PathLike, fps: float = 30.0, bit_rate: int = 8_000_000) -> None:
        av = require("av", "writing a video as it goes")
        self._av = av
        self.path = Path(path).expanduser()
        self.paths = (self.path,)
        if self.path.is_dir():
            raise FileFormatError(f"{self.path}: is a folder (a video file is written there)")
        output_folder(self.path.parent)
        if not (np.isfinite(fps) and fps > 0):
            raise InputError(f"video frame rate must be positive, got {fps}")
        self.fps = Fraction(float(fps)).limit_denominator(1001)
        self.bit_rate = int(bit_rate)
        try:
            self._out = av.open(str(self.path), "w", format="mp4",
                                options={"movflags": "frag_every_frame+empty_moov+default_base_moof",
                                         "flush_packets": "1"})
        except (OSError, av.FFmpegError) as exc:
            raise FileFormatError(f"{self.path}: cannot write the video: {exc}") from None
        self._stream = None
        self.size: tuple[int, int] | None = None

    def write(self, frame: np.ndarray) -> bool:
        """One frame; a frame of another size than the first is an InputError."""
        img = np.asarray(frame)
        if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
            raise InputError(f"a video frame is a BGR uint8 image (h, w, 3), got {img.dtype} {img.shape}")
        h, w = img.shape[:2]
        if self._stream is None:
            self.size = (w, h)
            s = self._stream = self._out.add_stream("mpeg4", rate=self.fps)
            s.width, s.height, s.pix_fmt = w + w % 2, h + h % 2, "yuv420p"
            s.bit_rate = self.bit_rate
        elif (w, h) != self.size:
            raise InputError(f"video frame of {w}x{h} pixels after frames of {self.size[0]}x{self.size[1]}")
        if w % 2 or h % 2:
            img = np.pad(img, ((0, h % 2), (0, w % 2), (0, 0)))
        for packet in self._stream.encode(self._av.VideoFrame.from_ndarray(np.ascontiguousarray(img),
                                                                           format="bgr24")):
            self._out.mux(packet)
        self.rows += 1
        return True

    def _close(self) -> None:
        if self._stream is not None:
            for packet in self._stream.encode(None):
                self._out.mux(packet)
        self._out.close()
