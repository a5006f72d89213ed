"""One distortion map captured live from a camera backend, for ``atris calib verify``.

The projector strobes the Walsh code row ``code_row`` of length N for the sub-frame
sequence numbers the camera reports; the block demodulator locks to the strobe phase from
the data (``lag=None``), since a real projector may switch a sub-frame late.
"""

from __future__ import annotations

import logging

import numpy as np
import numpy.typing as npt

from atris_node import codes
from atris_node.demod import BlockDemodulator
from atris_node.errors import CalibrationError
from atris_node.progress import progress

logger = logging.getLogger(__name__)

MAX_PERIODS = 8


def capture_map(backend: str, code_length: int = 16, code_row: int = 2,
                **settings: object) -> npt.NDArray[np.int32]:
    """(H, W) int32 distortion map of the scene before the camera of ``backend``.

    Reads up to ``MAX_PERIODS`` code periods and returns the first map demodulated with a
    locked phase; the projector is off and both devices closed afterwards.
    """
    import drivers

    chips = codes.walsh_chips(code_length, code_row)
    camera, projector = drivers.open_backend(backend, **settings)
    with camera, projector:
        demodulator: BlockDemodulator | None = None
        projector.strobe(int(chips[0]), 0)
        for index in progress(range(MAX_PERIODS * code_length), "live target", "sub-frame"):
            sub_frame = camera.read(timeout_s=2.0)
            projector.strobe(int(chips[(sub_frame.sequence + 1) % code_length]),
                             sub_frame.sequence + 1)
            demodulator = demodulator or BlockDemodulator(chips, bits=sub_frame.bits, lag=None)
            distortion_map = demodulator.push(sub_frame)
            if distortion_map is not None and index >= 2 * code_length:
                projector.off()
                logger.info("live map with strobe phase %d", distortion_map.phase)
                return np.asarray(distortion_map.values, dtype=np.int32)
    raise CalibrationError(f"no demodulated map from {backend!r} after {MAX_PERIODS} code "
                           "periods; is the projector strobing and the target lit?")
