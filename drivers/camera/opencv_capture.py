"""A camera read through ``cv2.VideoCapture``: a device index, a stream URL, a video file or
an image-sequence pattern (``/data/img_%04d.png``).

Colour frames are converted to grey. A failed read (device lost, end of file) raises
:class:`CameraError`; the frame counter is unchanged. Frame metadata carries the
back-end's own position and time stamp (``pos_frames``, ``pos_msec``) where it has them.
"""
from __future__ import annotations

import cv2
import numpy as np

from cell.clock import Clock
from cell.errors import ConfigError
from drivers.camera.base import CameraBase, CameraError


class OpenCVCamera(CameraBase):
    """``source``: device index (int) or URL / file / pattern (str).

    ``width``, ``height``: requested frame size in pixels (devices only; checked after
    opening, a device that does not honour it raises). ``api``: a ``cv2.CAP_*`` back-end
    preference (default ``cv2.CAP_ANY``).
    Raises :class:`~cell.errors.ConfigError` for a bad argument type at construction.
    """

    backend = "opencv"

    def __init__(self, source: int | str, *, width: int | None = None, height: int | None = None,
                 api: int = cv2.CAP_ANY, clock: Clock | None = None):
        super().__init__(clock)
        if isinstance(source, bool) or not isinstance(source, (int, str)) or source == "":
            raise ConfigError(f"opencv camera: source must be a device index or a URL/path, "
                              f"got {source!r}")
        for name, v in (("width", width), ("height", height)):
            if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v <= 0):
                raise ConfigError(f"opencv camera: {name} = {v!r} must be a positive integer")
        self.source, self.width, self.height, self.api = source, width, height, int(api)
        self._cap: cv2.VideoCapture | None = None

    def describe(self) -> str:
        return f"opencv camera {self.source!r}"

    def _open(self) -> None:
        cap = cv2.VideoCapture(self.source, self.api)
        if not cap.isOpened():
            cap.release()
            raise CameraError(f"{self.describe()}: cannot open (no such device, file or stream)")
        if self.width:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
        if self.height:
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        self._cap = cap

    def _close(self) -> None:
        if self._cap is not None:
            self._cap.release()
        self._cap = None

    def _grab(self):
        cap = self._cap
        ok, image = cap.read()
        if not ok or image is None:
            raise CameraError(f"{self.describe()}: no frame (end of stream or device lost)")
        if image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY if image.shape[2] == 3
                                 else cv2.COLOR_BGRA2GRAY)
        if image.dtype != np.uint8:
            raise CameraError(f"{self.describe()}: frame is {image.dtype}, need 8-bit")
        h, w = image.shape[:2]
        if (self.width and w != self.width) or (self.height and h != self.height):
            raise CameraError(f"{self.describe()}: frame is {w}x{h}, asked for "
                              f"{self.width or w}x{self.height or h}")
        return image, {"source": str(self.source), "api": cap.getBackendName(),
                       "pos_frames": cap.get(cv2.CAP_PROP_POS_FRAMES),
                       "pos_msec": cap.get(cv2.CAP_PROP_POS_MSEC)}
