"""The simulated camera's sensor noise, drawn one frame ahead on a spare core.

Drawing a frame's Gaussian noise (1280 x 1024 float32 samples) is most of the simulated
camera's CPU. The draw depends only on the generator's state, never on the scene, so the
next frame's noise can be drawn while the cell works on this one. numpy releases the GIL
while it fills an array, so on a machine with a free core the draw costs the cell no wall
time; the frames are the same as drawing each one when it is needed.
"""
from __future__ import annotations

import threading
from typing import NamedTuple

import numpy as np


class _Drawn(NamedTuple):
    shape: tuple[int, int]
    sigma: float
    state: dict          # the generator's state before this draw (to rewind to)
    out: np.ndarray


class NoiseAhead:
    """Sensor noise frames, ``sigma * N(0, 1)`` in float32 (the draw's own precision), drawn
    from ``rng`` in order, each next one drawn in a thread of its own
    (``sim-camera-noise``) while the caller uses the last.

    Frame k is always the k-th draw from ``rng``, exactly as :func:`numpy.random.Generator.
    standard_normal` then ``*= sigma`` gives it: the same frames as drawing each one when it
    is needed. A :meth:`take` whose shape or sigma differs from the frame drawn ahead rewinds
    ``rng`` to before that draw and draws anew, so even then nothing changes. Nothing else
    may draw from ``rng`` while this object owns it.

    The thread ends after ``idle_s`` wall seconds without a frame to draw (the next
    :meth:`take` starts another), so an object nobody closes does not keep its thread and
    its two frame buffers for good.

    :param rng: the generator this object now owns.
    """

    idle_s = 2.0

    def __init__(self, rng: np.random.Generator):
        self._rng = rng
        self._cv = threading.Condition()
        self._job: tuple | None = None          # (shape, sigma, out) waiting for or in the thread
        self._drawn: _Drawn | None = None
        self._buffers: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self._thread: threading.Thread | None = None
        self._closed = False

    def take(self, shape: tuple[int, int], sigma: float) -> np.ndarray:
        """The next noise frame for an image of ``shape`` (rows, columns) and noise ``sigma``
        (> 0) grey levels. The array is this object's: valid until the next :meth:`take`."""
        shape = (int(shape[0]), int(shape[1]))
        drawn = self._wait()
        if drawn is not None and (drawn.shape, drawn.sigma) != (shape, sigma):
            self._rng.bit_generator.state = drawn.state      # as if it had never been drawn
            drawn = None
        a, b = self._buffers.get(shape) or self._new_buffers(shape)
        out = _draw(self._rng, sigma, a) if drawn is None else drawn.out
        with self._cv:
            if self._closed:                                 # closed: no more drawing ahead
                return out
            self._job = (shape, sigma, b if out is a else a)
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="sim-camera-noise", daemon=True)
                self._thread.start()
            self._cv.notify_all()
        return out

    def close(self) -> None:
        """Wait for a draw under way and stop the thread. A later :meth:`take` still gets
        the frame drawn ahead, then draws in the caller's thread. Idempotent."""
        with self._cv:
            while self._job is not None:
                self._cv.wait()
            self._closed = True
            self._cv.notify_all()
            thread, self._thread = self._thread, None
        if thread is not None:
            thread.join()

    def _new_buffers(self, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        self._buffers[shape] = pair = (np.empty(shape, np.float32), np.empty(shape, np.float32))
        return pair

    def _wait(self) -> _Drawn | None:
        """Wait for the draw under way (if any); the frame drawn ahead, handed over."""
        with self._cv:
            while self._job is not None:
                self._cv.wait()
            drawn, self._drawn = self._drawn, None
        return drawn

    def _run(self) -> None:
        with self._cv:
            while True:
                while self._job is None and not self._closed:
                    if not self._cv.wait(self.idle_s) and self._job is None:
                        self._thread = None             # idle: the next take starts another
                        return
                if self._closed:
                    return
                shape, sigma, out = self._job
                state = self._rng.bit_generator.state
                self._cv.release()
                try:
                    _draw(self._rng, sigma, out)
                    drawn = _Drawn(shape, sigma, state, out)
                except Exception:                          # noqa: BLE001 -- drawn again by take, which raises
                    self._rng.bit_generator.state = state
                    drawn = None
                finally:
                    self._cv.acquire()
                self._drawn, self._job = drawn, None
                self._cv.notify_all()


def _draw(rng: np.random.Generator, sigma: float, out: np.ndarray) -> np.ndarray:
    rng.standard_normal(out.shape, dtype=np.float32, out=out)
    out *= sigma                                         # in float32, as the draw
    return out
