"""What every camera backend is: the :class:`Camera` protocol, the :class:`Frame` it returns,
and :class:`CameraBase`, which holds the lifecycle and the frame checks once for all backends.

Lifecycle: ``CLOSED --open--> OPEN --grab--> OPEN --close--> CLOSED``; any
other action raises :class:`CameraError` naming the camera and its state. A failed
``open`` or ``grab`` leaves the state and the frame counter as they were.

Frames are 8-bit grey (H, W) arrays, read-only, stamped with the injected clock's time
at the moment the backend handed the image over (seconds, ``Clock.now()``).
"""
from __future__ import annotations

import enum
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, ClassVar, Mapping, Protocol, runtime_checkable

import numpy as np

from cell.clock import Clock, MonotonicClock
from cell.errors import MeasurementError


class CameraError(MeasurementError):
    """A camera could not be opened or could not deliver a frame; names camera and cause."""


@dataclass(frozen=True)
class Frame:
    """One image from a camera.

    ``image``: (H, W) uint8 grey, read-only. ``timestamp_s``: clock time when grabbed.
    ``index``: 0, 1, 2, ... since the camera was created. ``metadata``: backend-specific,
    always with ``backend`` and ``source``.
    """

    image: np.ndarray
    timestamp_s: float
    index: int
    metadata: Mapping[str, Any] = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        return self.image.shape


class CameraState(enum.Enum):
    CLOSED = "closed"
    OPEN = "open"


_TRANSITIONS = {
    (CameraState.CLOSED, "open"): CameraState.OPEN,
    (CameraState.OPEN, "grab"): CameraState.OPEN,
    (CameraState.OPEN, "close"): CameraState.CLOSED,
}


@runtime_checkable
class Camera(Protocol):
    """A source of grey frames. Every backend in :mod:`drivers.camera` satisfies it."""

    @property
    def state(self) -> CameraState: ...

    def open(self) -> None:
        """Acquire the device/folder/scene. Raises :class:`CameraError` if it cannot, or if
        already open."""
        ...

    def grab(self) -> Frame:
        """The next frame. Raises :class:`CameraError` if not open, at end of stream, or if
        the image is unreadable or not 8-bit grey."""
        ...

    def close(self) -> None:
        """Release the device. Raises :class:`CameraError` if not open."""
        ...


class CameraBase:
    """Lifecycle and frame checks; a backend implements ``_open``, ``_grab``, ``_close``.

    ``_grab`` returns ``(image, metadata)``; a 3-channel BGR image is converted to grey by
    the backend, never here. Backends set ``backend`` and implement ``describe``.
    """

    backend: ClassVar[str] = "?"

    def __init__(self, clock: Clock | None = None):
        self._clock = clock if clock is not None else MonotonicClock()
        self._state = CameraState.CLOSED
        self._index = 0

    # -- backend hooks ---------------------------------------------------------------
    def _open(self) -> None:
        raise NotImplementedError

    def _grab(self) -> tuple[np.ndarray, dict]:
        raise NotImplementedError

    def _close(self) -> None:
        raise NotImplementedError

    def describe(self) -> str:
        """Short name of the camera for messages, e.g. ``folder camera '/data/run3'``."""
        return f"{self.backend} camera"

    # -- lifecycle -------------------------------------------------------------------
    @property
    def state(self) -> CameraState:
        return self._state

    def _next_state(self, action: str) -> CameraState:
        nxt = _TRANSITIONS.get((self._state, action))
        if nxt is None:
            raise CameraError(f"{self.describe()}: cannot {action} while {self._state.value}")
        return nxt

    def open(self) -> None:
        nxt = self._next_state("open")
        self._open()
        self._state = nxt

    def close(self) -> None:
        nxt = self._next_state("close")
        try:
            self._close()
        finally:
            self._state = nxt

    def grab(self) -> Frame:
        self._next_state("grab")
        image, meta = self._grab()
        if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.ndim != 2 \
                or image.size == 0:
            raise CameraError(f"{self.describe()}: backend returned "
                              f"{getattr(image, 'dtype', type(image).__name__)} "
                              f"{getattr(image, 'shape', '')}, not a non-empty 8-bit grey image")
        image = np.ascontiguousarray(image)
        image.flags.writeable = False
        frame = Frame(image, float(self._clock.now()), self._index,
                      MappingProxyType({"backend": self.backend, **meta}))
        self._index += 1
        return frame

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        if self._state is CameraState.OPEN:
            self.close()
