"""Videos a browser plays: H.264 in MP4 (``.mp4``) or VP9 in WebM (``.webm``), through PyAV
(FFmpeg's libraries; its wheels carry libx264 and libvpx).

Why these: every current browser plays H.264 MP4 (Safari and phones included) and VP9 WebM;
OpenCV's wheel writes neither a browser-playable MP4 (its 'mp4v' is MPEG-4 Part 2, which
browsers refuse; 'avc1' needs an H.264 encoder the wheel lacks) nor takes the options below.
Frames are yuv420p (what browsers decode; so both sides must be even). The MP4's index
(moov) follows the frames: FFmpeg's "faststart" reopens the file by name to move it, which the
atomic temporary file does not allow; a browser plays such a file from disk or over HTTP with
range requests. The file is
written through io.atomic: a reader never sees half a video, and a failed render leaves none."""

from __future__ import annotations

from contextlib import contextmanager
from fractions import Fraction
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import InputError
from .atomic import atomic_open

# suffix -> (container, codec, codec options). CRF 18 (H.264) and 15 (VP9) are visually
# lossless for rendered frames; "b": "0" puts libvpx in constant-quality mode.
VIDEO_FORMATS = {
    ".mp4": ("mp4", "libx264", {"crf": "18", "preset": "medium"}),
    ".webm": ("webm", "libvpx-vp9", {"crf": "15", "b": "0", "row-mt": "1"}),
}


def check_video_path(path: str | Path, flag: str = "--out") -> Path:
    path = Path(path)
    if path.suffix.lower() not in VIDEO_FORMATS:
        raise InputError(f"{flag} {path}: a video must end in {' or '.join(VIDEO_FORMATS)} "
                         "(H.264 MP4 or VP9 WebM, which browsers play)")
    return path


def fps_fraction(fps: float) -> Fraction:
    """The frame rate as the exact fraction the container stores (29.97 -> 2997/100)."""
    return Fraction(fps).limit_denominator(1001)


class _Unnamed:
    """The atomic temporary file as PyAV sees it: read, write, seek, and no name (given the file itself, PyAV took its
    ``name``, the descriptor number, for a path and opened "3")."""

    def __init__(self, handle) -> None:
        import os  # noqa: PLC0415

        self._file = os.fdopen(os.dup(handle.fileno()), "r+b")
        self.read, self.write, self.seek, self.tell = (self._file.read, self._file.write, self._file.seek,
                                                       self._file.tell)

    def close(self) -> None:
        self._file.close()  # flushed: atomic_open then fsyncs and renames its own handle


class VideoWriter:
    """Frames in, encoded packets out to an open binary file. Use :func:`open_video`."""

    def __init__(self, handle, path: Path, width: int, height: int, fps: float) -> None:
        import av  # noqa: PLC0415 - only when a video is written

        container, codec, options = VIDEO_FORMATS[path.suffix.lower()]
        self.file = _Unnamed(handle)
        self.container = av.open(self.file, mode="w", format=container)
        self.stream = self.container.add_stream(codec, rate=fps_fraction(fps), options=dict(options))
        self.stream.width, self.stream.height, self.stream.pix_fmt = width, height, "yuv420p"
        self.size = (width, height)
        self.frames = 0

    def write(self, image: np.ndarray) -> None:
        """image: [H, W, 3] uint8 RGB, or float in [0, 1] (clipped, rounded)."""
        import av  # noqa: PLC0415

        if image.dtype != np.uint8:
            image = (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        height, width = image.shape[:2]
        if (width, height) != self.size:
            raise ValueError(f"frame of {width}x{height} in a {self.size[0]}x{self.size[1]} video")
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image[..., :3]), format="rgb24")
        for packet in self.stream.encode(frame):
            self.container.mux(packet)
        self.frames += 1

    def finish(self) -> None:
        for packet in self.stream.encode(None):  # the encoder's delayed frames
            self.container.mux(packet)
        self.container.close()
        self.file.close()


@contextmanager
def open_video(path: str | Path, width: int, height: int, fps: float) -> Iterator[VideoWriter]:
    """A VideoWriter for ``path`` (.mp4 or .webm) of ``width`` x ``height`` (even) at ``fps``;
    the file appears complete when the block ends, and not at all when it raises."""
    path = check_video_path(path)
    if width % 2 or height % 2:
        raise ValueError(f"yuv420p video needs even sides, got {width}x{height}")
    with atomic_open(path, "wb") as handle:
        writer = VideoWriter(handle, path, width, height, fps)
        try:
            yield writer
        except BaseException:
            try:
                writer.container.close()   # the temporary file is removed by atomic_open
                writer.file.close()
            except Exception:  # noqa: BLE001 - the first error is the one to report
                pass
            raise
        writer.finish()


def read_video_frames(path: str | Path) -> tuple[list[np.ndarray], float, str]:
    """([H, W, 3] uint8 RGB frames, fps, codec name) of a video file (tests, tools)."""
    import av  # noqa: PLC0415

    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        frames = [frame.to_ndarray(format="rgb24") for frame in container.decode(stream)]
        return frames, float(stream.average_rate or stream.base_rate), stream.codec_context.name
