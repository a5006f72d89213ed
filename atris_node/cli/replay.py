"""``atris replay DIR``: demodulate a recording and print one line per distortion map.

    atris replay rec/                       # code read from the recorded chip column
    atris replay rec/ --code-length 16 --row 2 --json

Each output line (or JSON object) gives the sequence range of the map, the lag the
phase lock found, the SNR and the saturated fraction. Without ``--row`` the code is the
one ``atris record`` wrote into meta.json, else the shortest Walsh row whose
``chips[sequence % N]`` matches every recorded chip.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from atris_node.errors import ConfigError
from atris_node.types import DistortionMap
from drivers.recording import RecordingIndex
from drivers.replay import ReplayCamera, open_backend

#: code lengths tried when the code is read from the chip column
CODE_LENGTHS = (4, 8, 16, 32, 64, 128)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", help="recording directory written by 'atris record'")
    parser.add_argument("--code-length", type=int, default=None, help="code length N")
    parser.add_argument("--row", type=int, default=None, help="1-based Walsh row")
    parser.add_argument("--json", action="store_true", help="one JSON object per map")
    parser.add_argument("--realtime", action="store_true", help="pace at the recorded rate")


def _matches(index: RecordingIndex, chips: npt.NDArray[Any]) -> bool:
    known = index.chip >= 0
    expected = chips[index.sequence[known] % len(chips)]
    return bool(np.any(known)) and bool(np.array_equal(expected, index.chip[known]))


def infer_code(index: RecordingIndex, lengths: Sequence[int] = CODE_LENGTHS) -> tuple[int, int]:
    """(N, row) of the shortest Walsh code that explains the recorded chip column."""
    from atris_node.codes import walsh_chips

    for length in lengths:
        for row in range(2, length + 1):
            if _matches(index, np.asarray(walsh_chips(length, row), dtype=np.int8)):
                return length, row
    raise ConfigError("the recording's chip column matches no Walsh row of length "
                      f"{', '.join(map(str, lengths))}; give --code-length and --row")


def _code(args: argparse.Namespace, camera: ReplayCamera) -> tuple[int, int]:
    meta = camera.recording.meta
    if args.row is not None:
        return (args.code_length or meta.code_length or 16), args.row
    if meta.code_row:
        return meta.code_length, meta.code_row
    return infer_code(camera.recording.index)


def map_summary(dmap: DistortionMap) -> dict[str, Any]:
    """The fields printed for one distortion map."""
    return {"first_sequence": dmap.first_sequence, "last_sequence": dmap.last_sequence,
            "lag": dmap.phase, "snr": round(float(dmap.snr), 3), "dropped": dmap.dropped,
            "saturated_fraction": round(float(np.mean(dmap.saturated)), 6)}


def _line(row: dict[str, Any]) -> str:
    return (f"seq {row['first_sequence']}-{row['last_sequence']} lag {row['lag']} "
            f"snr {row['snr']:.1f} saturated {row['saturated_fraction']:.4f} "
            f"dropped {row['dropped']}")


def run(args: argparse.Namespace) -> int:
    from atris_node.codes import walsh_chips
    from atris_node.demod import BlockDemodulator

    camera, projector = open_backend(args.path, realtime=args.realtime)
    with camera, projector:
        length, row = _code(args, camera)
        demod = BlockDemodulator(walsh_chips(length, row), bits=camera.bits, lag=None)
        for sub in camera.frames():
            dmap = demod.push(sub)
            if dmap is not None:
                summary = map_summary(dmap)
                print(json.dumps(summary) if args.json else _line(summary), flush=True)
    return 0
