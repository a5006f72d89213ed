"""``atris record``: read sub-frames from any camera backend into a recording directory.

    atris record --driver sim --scene indoor_lab --frames 256 --out rec/
    atris record --driver depthai --rate-hz 120 --exposure-us 500 --frames 1024 --out rec/

The projector is strobed with Walsh row ``--row`` of length ``--code-length`` (the chip
of each sub-frame is stored with it); ``--row 0`` records with the projector off. The
format is described in ``drivers/recording.py`` and ``docs/drivers.md``.
"""

from __future__ import annotations

import argparse
import logging
import os
from typing import Any

import drivers
from drivers.recording import RecordingWriter, record

logger = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--driver", default=os.environ.get("ATRIS_DRIVER", "sim"),
                        choices=sorted(drivers.BACKENDS), help="camera backend (default sim)")
    parser.add_argument("--scene", default="indoor_lab", help="simulator scene (sim)")
    parser.add_argument("--seed", type=int, default=None, help="simulator noise seed (sim)")
    parser.add_argument("--path", default=None, help="recording to read (replay)")
    parser.add_argument("--rate-hz", type=float, default=None, help="sub-frame rate (depthai)")
    parser.add_argument("--exposure-us", type=float, default=None, help="exposure time, µs")
    parser.add_argument("--frames", type=int, required=True, help="sub-frames to record")
    parser.add_argument("--out", required=True, help="new directory for the recording")
    parser.add_argument("--code-length", type=int, default=16, help="code length N")
    parser.add_argument("--row", type=int, default=2,
                        help="1-based Walsh row strobed while recording; 0 = projector off")


def backend_settings(args: argparse.Namespace) -> dict[str, Any]:
    """The keyword settings of the chosen backend that were given on the command line."""
    wanted = {"sim": ("scene", "seed", "rate_hz"), "replay": ("path",), "depthai": ("rate_hz",)}
    given = {key: getattr(args, key) for key in wanted.get(args.driver, ())}
    return {key: value for key, value in given.items() if value is not None}


def _chips(args: argparse.Namespace) -> list[int] | None:
    if args.row == 0:
        return None
    from atris_node.codes import walsh_chips

    return [int(c) for c in walsh_chips(args.code_length, args.row)]


def run(args: argparse.Namespace) -> int:
    chips = _chips(args)
    camera, projector = drivers.open_backend(args.driver, **backend_settings(args))
    with camera, projector:
        if args.exposure_us is not None:
            camera.set_exposure_us(args.exposure_us)
        code = (args.code_length, args.row) if chips is not None else (0, 0)
        with RecordingWriter(args.out, rate_hz=camera.rate_hz, source=args.driver,
                             code=code) as writer:
            count = record(camera, projector, writer, args.frames, chips=chips)
    print(f"recorded {count} sub-frames to {args.out}")
    return 0
