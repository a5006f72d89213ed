"""Shared memory between the unit and its map process: the map slot.

A complete map is written once into the *map slot* (its values and saturation mask, the
size of the calibrated image) before the map process is told to measure it; nothing big
is pickled. The map's raw sub-frames (:class:`~atris_node.types.WindowFrames`: N + 1
sub-frames, 76 MB at 2048x1088 16-bit) are not copied at all: the pipeline reads them only
at its peaks (:func:`atris_node.pipeline.temporal.window_series`, a few thousand pixels),
so the map process asks the unit for those values while it measures
(:mod:`atris_node.node.mapprocess`).

Segments are named ``atris_maps_<pid>_<n>`` and unlinked by :meth:`Segment.close`.

Example:
    >>> segment = Segment.create(64)
    >>> segment.array((2, 4), "int32")[:] = 7
    >>> seen = Segment.attach(segment.name)
    >>> int(seen.array((2, 4), "int32").sum())
    56
    >>> seen.close()
    >>> segment.close()
"""

from __future__ import annotations

import itertools
import logging
import os
from dataclasses import dataclass
from multiprocessing import shared_memory
from typing import Any

import numpy as np
import numpy.typing as npt

from atris_node.types import DistortionMap

logger = logging.getLogger(__name__)

PREFIX = "atris_maps_"
_names = itertools.count()


class Segment:
    """One shared-memory segment; the creating side unlinks it on :meth:`close`."""

    def __init__(self, shm: shared_memory.SharedMemory, owner: bool) -> None:
        self._shm: shared_memory.SharedMemory | None = shm
        self.name = shm.name
        self.size = shm.size
        self._owner = owner

    @classmethod
    def create(cls, size: int) -> Segment:
        name = f"{PREFIX}{os.getpid()}_{next(_names)}"
        return cls(shared_memory.SharedMemory(name=name, create=True, size=max(size, 1)), True)

    @classmethod
    def attach(cls, name: str) -> Segment:
        return cls(shared_memory.SharedMemory(name=name), False)

    def array(self, shape: tuple[int, ...], dtype: Any, offset: int = 0) -> npt.NDArray[Any]:
        """A C-contiguous view of ``shape`` and ``dtype`` at byte ``offset``."""
        assert self._shm is not None, "segment closed"
        return np.ndarray(shape, dtype=np.dtype(dtype), buffer=self._shm.buf, offset=offset)

    def close(self) -> None:
        """Detach (and unlink, on the creating side); safe to call more than once."""
        shm, self._shm = self._shm, None
        if shm is None:
            return
        try:
            shm.close()
        except BufferError:  # a view still alive; the mapping goes with the process
            logger.debug("segment %s still has views; left mapped", self.name)
        if self._owner:
            shm.unlink()


@dataclass(frozen=True)
class MapNotice:
    """What the map process needs to see a map in the map slot: the map's own small
    fields, its (H, W) and the values' dtype, and its window's signs and the offset of the OFF frame
    before it (``window`` False: the map has no window)."""

    fields: dict[str, Any]
    shape: tuple[int, int]
    values_dtype: str
    window: bool = False
    signs: tuple[int, ...] = ()
    before: int | None = None


#: the DistortionMap fields passed as they are (all but the arrays and the window)
SMALL_FIELDS = ("code_length", "first_sequence", "last_sequence", "first_time_s",
                "last_time_s", "phase", "dropped", "processing_gain", "snr", "extra",
                "exposure_us")


def map_bytes(height: int, width: int) -> int:
    """Bytes of the map slot: int32 values (the widest) and the bool mask."""
    return height * width * 5


def notice_of(dmap: DistortionMap) -> MapNotice:
    """The notice of ``dmap`` (written to the map slot)."""
    fields = {name: getattr(dmap, name) for name in SMALL_FIELDS}
    shape = (int(dmap.values.shape[0]), int(dmap.values.shape[1]))
    window = dmap.window
    if window is None:
        return MapNotice(fields, shape, dmap.values.dtype.str)
    before = None if window.before is None else window.before[0]
    return MapNotice(fields, shape, dmap.values.dtype.str, True, tuple(window.signs), before)
