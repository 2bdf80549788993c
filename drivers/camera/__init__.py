"""Camera backends, chosen by name and imported only when asked for.

``create("sim", model=..., scene=...)``, ``create("folder", path=...)``,
``create("opencv", source=0)``; ``from_config({"backend": "folder", "path": ...})`` does the
same from the cell config's ``camera`` section. Every backend satisfies
:class:`drivers.camera.base.Camera`; nothing outside this package knows which one it has.
"""
from __future__ import annotations

from typing import Any, Mapping

from cell.errors import ConfigError
from drivers import registry
from drivers.camera.base import Camera, CameraError, CameraState, Frame

#: name -> "module:class" (:mod:`drivers.registry`); imported on first use only (OpenCV
#: capture pulls in video back-ends, the sim pulls in the renderer)
BACKENDS: dict[str, str] = {
    "opencv": "drivers.camera.opencv_capture:OpenCVCamera",
    "folder": "drivers.camera.folder:FolderCamera",
    "sim": "drivers.camera.sim:SimCamera",
}

__all__ = ["BACKENDS", "Camera", "CameraError", "CameraState", "Frame", "backend_class",
           "create", "from_config"]


def backend_class(name: str) -> type:
    """The class of backend ``name``. Raises :class:`ConfigError` for an unknown name."""
    return registry.load(BACKENDS, name, "camera.backend")


def create(name: str, **options: Any) -> Camera:
    """Build (not open) a camera of backend ``name`` with the backend's keyword options.

    Raises :class:`ConfigError` naming the backend for an unknown name or option.
    """
    cls = backend_class(name)
    try:
        return cls(**options)
    except TypeError as exc:
        raise ConfigError(f"camera backend {name!r}: {exc}") from None


def from_config(section: Mapping[str, Any]) -> Camera:
    """Build a camera from the config's ``camera`` section: ``backend`` plus its options."""
    if not isinstance(section, Mapping) or "backend" not in section:
        raise ConfigError(f"camera: section must be a mapping with a 'backend' key, got {section!r}")
    options = dict(section)
    return create(options.pop("backend"), **options)
