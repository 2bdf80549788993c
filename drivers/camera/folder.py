"""Replay a folder of images as a camera, in name order (natural: ``img2`` before ``img10``).

Used to re-run the vision on images saved from a real cell. Colour images are converted
to grey; 16-bit or otherwise unreadable files raise :class:`CameraError` naming the file,
and the replay stays on that file (nothing is skipped silently). At the end of the folder
``grab`` raises, or starts again if ``loop=True``.
"""
from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from cell.clock import Clock
from cell.errors import ConfigError
from drivers.camera.base import CameraBase, CameraError

EXTENSIONS = (".png", ".bmp", ".tif", ".tiff", ".jpg", ".jpeg", ".pgm", ".pnm")


def _natural_key(path: Path):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path.name)]


class FolderCamera(CameraBase):
    """Frames from the image files in ``path`` (extensions: :data:`EXTENSIONS`).

    Raises :class:`~cell.errors.ConfigError` at construction for a bad ``path`` type;
    ``open`` raises :class:`CameraError` if the folder is missing or holds no images.
    """

    backend = "folder"

    def __init__(self, path: str | Path, *, loop: bool = False, clock: Clock | None = None):
        super().__init__(clock)
        if not isinstance(path, (str, Path)) or not str(path):
            raise ConfigError(f"folder camera: path must be a folder name, got {path!r}")
        self.path = Path(path)
        self.loop = bool(loop)
        self._files: list[Path] = []
        self._pos = 0

    def describe(self) -> str:
        return f"folder camera '{self.path}'"

    @property
    def files(self) -> list[Path]:
        """The image files of the open folder, in replay order."""
        return list(self._files)

    def _open(self) -> None:
        if not self.path.is_dir():
            raise CameraError(f"{self.describe()}: no such folder")
        files = sorted((p for p in self.path.iterdir()
                        if p.is_file() and p.suffix.lower() in EXTENSIONS), key=_natural_key)
        if not files:
            raise CameraError(f"{self.describe()}: no image files ({', '.join(EXTENSIONS)})")
        self._files, self._pos = files, 0

    def _close(self) -> None:
        self._files = []

    @property
    def count(self) -> int:
        """Images in the folder (known once opened)."""
        return len(self._files)

    def _grab(self):
        if self._pos >= len(self._files):
            if not self.loop:
                raise CameraError(f"{self.describe()}: end of folder after "
                                  f"{len(self._files)} images")
            self._pos = 0
        path = self._files[self._pos]
        image = self._read(path)
        meta = {"source": str(self.path), "file": str(path), "position": self._pos}
        self._pos += 1
        return image, meta

    def _read(self, path: Path) -> np.ndarray:
        try:
            data = np.fromfile(path, dtype=np.uint8)      # unicode-safe, unlike cv2.imread
        except OSError as exc:
            raise CameraError(f"{self.describe()}: cannot read '{path}': {exc}") from None
        image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
        if image is None:
            raise CameraError(f"{self.describe()}: '{path}' is not a readable image "
                              f"({data.size} bytes)")
        if image.dtype != np.uint8:
            raise CameraError(f"{self.describe()}: '{path}' is {image.dtype}, only 8-bit "
                              f"images are supported")
        if image.ndim == 3 and image.shape[2] == 4:
            image = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
        elif image.ndim == 3 and image.shape[2] == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        elif image.ndim == 3 and image.shape[2] == 1:
            image = image[:, :, 0]
        if image.ndim != 2:
            raise CameraError(f"{self.describe()}: '{path}' has shape {image.shape}, "
                              f"not a grey or colour image")
        return image
