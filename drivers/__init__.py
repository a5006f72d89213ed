"""Camera and projector backends, chosen by name and imported lazily.

A missing vendor SDK (depthai) never breaks ``import drivers``: the backend module is
imported only when its name is asked for, as python-can does with its interfaces.
"""

from __future__ import annotations

import importlib
from typing import Any

from atris_node.errors import DriverError
from drivers.base import Camera, Projector

#: backend name -> (module, factory). The factory takes keyword settings and returns
#: ``(camera, projector)``.
BACKENDS: dict[str, tuple[str, str]] = {
    "sim": ("drivers.sim", "open_backend"),
    "depthai": ("drivers.depthai_backend", "open_backend"),
    "replay": ("drivers.replay", "open_backend"),
}


def open_backend(name: str, **settings: Any) -> tuple[Camera, Projector]:
    """Open the backend called ``name`` and return its camera and projector."""
    if name not in BACKENDS:
        raise DriverError(f"unknown driver {name!r}; accepted: {', '.join(sorted(BACKENDS))}")
    module_name, factory_name = BACKENDS[name]
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise DriverError(f"driver {name!r} cannot be loaded: {exc}") from exc
    factory = getattr(module, factory_name)
    return factory(**settings)


__all__ = ["BACKENDS", "Camera", "Projector", "open_backend"]
