"""Frame sources for tracking (the paper's system runs on a camera stream, Section 6): a
video file, a folder of images, or a live camera, read one frame at a time with OpenCV.

`Frames` is an iterable that opens its source when iterated and releases it at the end
(or on `close`, or when its `with` block ends). Frames come as OpenCV gives them, BGR
uint8 `(h, w, 3)`, or grey `(h, w)` with `gray=True`. A folder's images are read in
natural order of their names (`frame2.png` before `frame10.png`); files that are not
images are skipped.

Plain numpy and OpenCV (imported inside the functions): nothing here is traced.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..geometry._validate import no_type_check

__all__ = ["Frames", "IMAGE_SUFFIXES", "open_frames"]

#: The file suffixes a folder source reads as images (lower case).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp")


def _natural_key(path: Path) -> list:
    """Sort key of a file name with its digit runs compared as numbers."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", path.name)]


class Frames:
    """A source of frames: a video file, a folder of images or a camera (see
    `open_frames`). Iterating yields the frames in order, `uint8` BGR `(h, w, 3)` or grey
    `(h, w)`; a video or a camera is opened when the iteration starts and released when
    it ends. A camera stream ends when the camera stops giving frames, or at `stop`.

    **Attributes:**
    - `kind`: `"video"`, `"folder"` or `"camera"`.
    - `source`: the path (a `Path`) or the camera index.
    - `files`: a folder's image files, in the order read (empty for the others).
    """

    def __init__(self, kind: str, source, files: list[Path], gray: bool, start: int, stop):
        self.kind, self.source, self.files = kind, source, files
        self.gray, self.start, self.stop = gray, start, stop
        self._capture = None

    def _open_capture(self):
        import cv2

        target = self.source if self.kind == "camera" else str(self.source)
        capture = cv2.VideoCapture(target)
        if not capture.isOpened():
            capture.release()
            raise ValueError(f"source {self.source!r} could not be opened by OpenCV")
        return capture

    def _convert(self, frame: np.ndarray) -> np.ndarray:
        import cv2

        if frame.ndim == 2:
            return frame if self.gray else cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
        if frame.shape[2] == 4:
            frame = cv2.cvtColor(frame, cv2.COLOR_BGRA2BGR)
        return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY) if self.gray else frame

    def __len__(self) -> int:
        """The number of frames the source will give: a folder's images; a video's frame
        count as its container reports it (OpenCV's estimate: a frame more or less than
        decode, as for `box.mp4`'s 456 of 455); a camera's is unknown: `stop - start`
        when `stop` is set, else a `TypeError`, as for any iterable without a length."""
        if self.kind == "folder":
            total = len(self.files)
        elif self.kind == "video":
            import cv2

            capture = self._open_capture()
            total = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
            capture.release()
        elif self.stop is not None:
            return self.stop - self.start
        else:
            raise TypeError("a camera stream has no length (give stop to bound it)")
        end = total if self.stop is None else min(self.stop, total)
        return max(end - self.start, 0)

    @property
    def fps(self) -> float:
        """The video's or camera's frame rate as OpenCV reports it (0 when unknown, and for
        a folder)."""
        if self.kind == "folder":
            return 0.0
        import cv2

        capture = self._open_capture() if self._capture is None else self._capture
        fps = float(capture.get(cv2.CAP_PROP_FPS))
        if capture is not self._capture:
            capture.release()
        return fps if np.isfinite(fps) and fps > 0 else 0.0

    def __iter__(self) -> Iterator[np.ndarray]:
        if self.kind == "folder":
            yield from self._iter_folder()
            return
        import cv2

        self.close()
        self._capture = self._open_capture()
        try:
            index = 0
            if self.start and self.kind == "video":
                self._capture.set(cv2.CAP_PROP_POS_FRAMES, self.start)
                index = int(self._capture.get(cv2.CAP_PROP_POS_FRAMES))
            while self.stop is None or index < self.stop:
                ok, frame = self._capture.read()
                if not ok or frame is None:
                    break
                if index >= self.start:
                    yield self._convert(frame)
                index += 1
        finally:
            self.close()

    def _iter_folder(self) -> Iterator[np.ndarray]:
        import cv2

        flag = cv2.IMREAD_GRAYSCALE if self.gray else cv2.IMREAD_COLOR
        for path in self.files[self.start : self.stop]:
            frame = cv2.imread(str(path), flag)
            if frame is None:
                raise ValueError(f"source: image {str(path)!r} could not be read by OpenCV")
            yield frame

    def close(self) -> None:
        """Release the video or camera if it is open (iterating again reopens it)."""
        if self._capture is not None:
            self._capture.release()
            self._capture = None

    def __enter__(self) -> Frames:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Frames(kind={self.kind!r}, source={self.source!r})"


@no_type_check
def open_frames(
    source: str | os.PathLike | int,
    *,
    gray: bool = False,
    start: int = 0,
    stop: int | None = None,
) -> Frames:
    """A frame source for tracking.

    **Arguments:**
    - `source`: a video file (any format OpenCV's `VideoCapture` reads), a folder of
      images (`IMAGE_SUFFIXES`, read in natural order of their names), or a camera index
      (an `int` >= 0, opened live with `cv2.VideoCapture(index)`).
    - `gray`: yield grey `(h, w)` frames instead of BGR `(h, w, 3)`.
    - `start`, `stop`: the frames `start <= i < stop` only (`stop=None`: to the end).

    **Returns:** a `Frames` (iterate it; `len()` for a video or a folder). A video or a
    folder is checked now; a camera is opened when the iteration starts.

    **Raises:** `ValueError` naming `source` for a missing path, a folder without images,
    a video OpenCV cannot open or a negative camera index (and, when iterating, for a
    camera that cannot be opened or an unreadable image); naming `start` or `stop` for a
    bad range.
    """
    for label, value in (("start", start), ("stop", stop)):
        if value is None and label == "stop":
            continue
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
            raise ValueError(f"{label} must be an int >= 0, got {value!r}")
    if stop is not None and stop < start:
        raise ValueError(f"stop must be >= start ({start}), got {stop}")
    gray = bool(gray)
    if isinstance(source, bool) or not isinstance(source, str | os.PathLike | int | np.integer):
        raise ValueError(f"source must be a path or a camera index, got {type(source).__name__}")
    if isinstance(source, int | np.integer):
        if source < 0:
            raise ValueError(f"source must be a camera index >= 0, got {source}")
        return Frames("camera", int(source), [], gray, int(start), stop)
    path = Path(source)
    if path.is_dir():
        files = [p for p in path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES]
        if not files:
            raise ValueError(f"source {str(path)!r} is a folder without images")
        return Frames("folder", path, sorted(files, key=_natural_key), gray, int(start), stop)
    if not path.is_file():
        raise ValueError(f"source {str(path)!r} is neither a file nor a folder")
    frames = Frames("video", path, [], gray, int(start), stop)
    frames._open_capture().release()  # checks now that OpenCV reads it
    return frames
