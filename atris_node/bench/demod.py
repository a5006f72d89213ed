"""``atris bench demod [--json]``: demodulation time per sub-frame against a plain copy.

For each frame format (640x400 8-bit, 1280x800 8-bit, 2048x1088 10-bit) a stream of
distinct synthetic sub-frames (ambient gradient, noise, strobed horizontal lines) is pushed
through :class:`~atris_node.demod.BlockDemodulator` and
:class:`~atris_node.demod.SlidingDemodulator` (every ``push``: validation, sequence
tracking, the update, the full-scale check, and for each map the statistics), and the
same frames are copied with ``np.copyto`` in the same run, interleaved repeat by repeat
so that both see the same machine load. Rows (JSON fields relied on by
other tools): ``width``, ``height``, ``bits``, ``mode`` ("block" or "sliding"), ``ms``
(median ms per sub-frame), ``copy_ms`` and ``ratio`` (``ms / copy_ms``).
"""

from __future__ import annotations

import argparse
import json
import logging
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import numpy.typing as npt

from atris_node import codes
from atris_node.bench._timing import time_interleaved
from atris_node.demod import BlockDemodulator, Kernels, SlidingDemodulator
from atris_node.types import SubFrame

logger = logging.getLogger(__name__)

#: (width, height, bits) of the benchmarked formats
FORMATS = ((640, 400, 8), (1280, 800, 8), (2048, 1088, 10))
MODES = {"block": BlockDemodulator, "sliding": SlidingDemodulator}
Pixels = npt.NDArray[np.uint8] | npt.NDArray[np.uint16]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print the rows as a JSON list")
    parser.add_argument("--length", type=int, default=16, help="code length N (default 16)")
    parser.add_argument("--repeats", type=int, default=9, help="timed repeats (default 9)")
    parser.add_argument("--saturated", action="store_true",
                        help="clip the line cores at full scale in every ON sub-frame")


def scene(width: int, height: int, bits: int, chips: npt.NDArray[np.uint8], *,
          saturated: bool = False, seed: int = 0) -> list[Pixels]:
    """2N sub-frames, (height, width) uint8/uint16: ambient ramp + noise + lines on ON chips.

    Sub-frame i shows chip ``chips[i % N]``. Levels are fractions of full scale: ambient
    0.2..0.5, noise +-2 %, lines +0.3 (clipped to full scale on the line cores when
    ``saturated``).
    """
    full = (1 << bits) - 1
    rng = np.random.default_rng(seed)
    ramp = np.linspace(0.2, 0.5, width)[None, :] * full
    lines = np.zeros((height, 1))
    lines[height // 16::height // 8] = 0.3 * full
    dtype = np.uint8 if bits == 8 else np.uint16
    frames: list[Pixels] = []
    for i in range(2 * chips.size):
        noise = rng.integers(-full // 50, full // 50 + 1, (height, width))
        frame = ramp + noise + lines * chips[i % chips.size]
        if saturated and chips[i % chips.size]:
            frame[height // 16::height // 8] = full
        frames.append(np.clip(frame, 0, full).astype(dtype))
    return frames


def _stream(frames: list[Pixels], bits: int) -> Iterator[SubFrame]:
    sequence = 0
    while True:
        pixels = frames[sequence % len(frames)]
        yield SubFrame(pixels, sequence, sequence / 480.0, sequence / 480.0, 100.0, bits=bits)
        sequence += 1


def _mode_work(mode: str, frames: list[Pixels], chips: npt.NDArray[np.uint8],
               bits: int) -> tuple[Callable[[], object], int]:
    """``push`` of 2N sub-frames on a primed demodulator, and that count."""
    demod = MODES[mode](chips, bits, lag=0)
    stream = _stream(frames, bits)
    for _ in range(chips.size):
        demod.push(next(stream))
    count = 2 * chips.size

    def work() -> None:
        for _ in range(count):
            demod.push(next(stream))

    return work, count


def _copy_work(frames: list[Pixels]) -> tuple[Callable[[], object], int]:
    """``np.copyto`` of the same frames into one target, and their count."""
    target = np.empty_like(frames[0])

    def work() -> None:
        for frame in frames:
            np.copyto(target, frame)

    return work, len(frames)


def reference_passes(frames: list[Pixels], repeats: int) -> dict[str, float]:
    """Median ms per sub-frame of the passes the block update is made of, for the docs.

    ``copy``: ``np.copyto``; ``add``: ``np.add`` into an int16 accumulator (through an
    int16 view for uint16);
    ``add+max fused by chunk``: the demodulator's kernel, the addition and the full-scale
    check per cached chunk of rows; ``max``: a separate full-scale check; ``maximum into``:
    a running maximum into a preallocated buffer.
    """
    acc = np.zeros(frames[0].shape, np.int16)
    peak = np.zeros_like(frames[0])
    view = [f.view(np.int16) if f.dtype == np.uint16 else f for f in frames]
    kernels = Kernels(np.dtype(np.int16), (frames[0].shape[0], frames[0].shape[1]), 1 << 16)
    passes = {
        "add": lambda: [np.add(acc, f, out=acc) for f in view],
        "add+max fused by chunk": lambda: [kernels.add(acc, f, 1) for f in frames],
        "max": lambda: [f.max() for f in frames],
        "maximum into": lambda: [np.maximum(peak, f, out=peak) for f in frames],
    }
    work = {"copy": _copy_work(frames)}
    work.update({name: (fn, len(frames)) for name, fn in passes.items()})
    return {k: t.median_ms for k, t in time_interleaved(work, repeats).items()}


def measure(width: int, height: int, bits: int, length: int, *, repeats: int,
            saturated: bool = False) -> list[dict[str, Any]]:
    """The rows of one frame format: one per mode."""
    chips = codes.walsh_chips(length, codes.code_set(length)[-1])
    frames = scene(width, height, bits, chips, saturated=saturated)
    work = {"copy": _copy_work(frames)}
    work.update({mode: _mode_work(mode, frames, chips, bits) for mode in MODES})
    timings = time_interleaved(work, repeats)
    copy_ms = timings["copy"].median_ms
    rows = []
    for mode in MODES:
        ms = timings[mode].median_ms
        rows.append({"width": width, "height": height, "bits": bits, "mode": mode,
                     "ms": round(ms, 6), "copy_ms": round(copy_ms, 6),
                     "ratio": round(ms / copy_ms, 3)})
    return rows


def _print_table(rows: list[dict[str, Any]]) -> None:
    print(f"{'format':<18} {'mode':<8} {'ms':>8} {'copy_ms':>8} {'ratio':>6}")
    for r in rows:
        fmt = f"{r['width']}x{r['height']} {r['bits']}-bit"
        print(f"{fmt:<18} {r['mode']:<8} {r['ms']:>8.3f} {r['copy_ms']:>8.3f} "
              f"{r['ratio']:>6.2f}")


def run(args: argparse.Namespace) -> int:
    length = codes.check_length(args.length)
    rows = []
    for width, height, bits in FORMATS:
        logger.info("timing %dx%d %d-bit", width, height, bits)
        rows += measure(width, height, bits, length, repeats=args.repeats,
                        saturated=args.saturated)
    if args.json:
        print(json.dumps(rows))
        return 0
    _print_table(rows)
    print("\nsingle passes, ms per sub-frame (int16 accumulator):")
    for width, height, bits in FORMATS:
        chips = codes.walsh_chips(length, 2)
        passes = reference_passes(scene(width, height, bits, chips), args.repeats)
        print(f"  {width}x{height} {bits}-bit: "
              + ", ".join(f"{k} {v:.3f}" for k, v in passes.items()))
    return 0
