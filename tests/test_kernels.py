"""The compiled kernels as the node uses them: warmed before the first map, fed any map
dtype, read-only maps included."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from numba.core.registry import CPUDispatcher

from atris_node.pipeline import (
    alignment_kernels,
    identity_kernels,
    peaks_kernels,
    radiometry_kernels,
    rivals_kernels,
    verdicts_kernels,
)
from atris_node.pipeline.bands import Band
from atris_node.pipeline.peaks import ExtractorSettings, extract_lines

MODULES = (peaks_kernels, identity_kernels, alignment_kernels, rivals_kernels,
           verdicts_kernels, radiometry_kernels)


def _public_kernels(module: ModuleType) -> list[str]:
    return [name for name, value in vars(module).items()
            if isinstance(value, CPUDispatcher) and not name.startswith("_")
            and value.__module__ == module.__name__]


@pytest.mark.parametrize("module", MODULES, ids=lambda m: m.__name__)
def test_warm_up_calls_every_public_kernel(module: ModuleType,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    kernels, called = _public_kernels(module), set()
    assert kernels
    for name in kernels:
        kernel = getattr(module, name)

        def record(*args: object, _name: str = name, _kernel: object = kernel) -> object:
            called.add(_name)
            return _kernel(*args)  # type: ignore[operator]

        monkeypatch.setattr(module, name, record)
    module.warm_up()  # type: ignore[attr-defined]
    assert set(kernels) <= called, sorted(set(kernels) - called)


def _map() -> np.ndarray:
    """Three horizontal lines over a noisy background, 120x96, whole DN within 0..255."""
    rng = np.random.default_rng(3)
    values = rng.normal(20.0, 3.0, (120, 96))
    rows = np.arange(120)[:, None]
    for centre in (30.0, 60.0, 90.0):
        values += 200.0 * np.exp(-0.5 * ((rows - centre) / 1.5) ** 2)
    return np.clip(np.round(values), 0, 255)


BANDS = (Band(0, 15, 45), Band(1, 45, 75), Band(2, 75, 105))


@pytest.mark.parametrize("dtype", [np.int16, np.int32, np.float32, np.uint8, np.uint16,
                                   np.int64])
def test_any_map_dtype_and_read_only_maps_give_the_same_samples(dtype: type) -> None:
    mask = np.zeros((120, 96), bool)
    reference = extract_lines(_map(), mask, BANDS, ExtractorSettings())
    values = _map().astype(dtype)
    values.flags.writeable = False  # as the demodulators hand maps out
    mask.flags.writeable = False
    got = extract_lines(values, mask, BANDS, ExtractorSettings())
    assert len(reference.samples) == 3 * 96
    np.testing.assert_array_equal(got.samples.line, reference.samples.line)
    np.testing.assert_array_equal(got.samples.col_px, reference.samples.col_px)
    np.testing.assert_allclose(got.samples.row_px, reference.samples.row_px, atol=1e-9)


def test_map_values_widens_what_the_kernels_do_not_take() -> None:
    assert peaks_kernels.map_values(np.zeros((2, 2), np.uint8)).dtype == np.int32
    assert peaks_kernels.map_values(np.zeros((2, 2), np.uint32)).dtype == np.float64
    assert peaks_kernels.map_values(np.zeros((2, 2), np.float16)).dtype == np.float64
    strided = np.zeros((4, 4), np.int16)[:, ::2]
    assert peaks_kernels.map_values(strided).flags.c_contiguous


def test_kernels_are_cached_only_where_a_cache_can_be_written(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from atris_node import jit

    blocked = tmp_path / "a_file"
    blocked.write_text("not a directory")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocked / "cache"))
    monkeypatch.setattr(jit.numba.config, "CACHE_DIR", "", raising=False)
    assert jit.cache_dir(blocked, "k") == ""  # no directory can be made
    monkeypatch.setattr(jit.numba.config, "CACHE_DIR", str(tmp_path / "numba"), raising=False)
    assert jit.cache_dir(blocked, "k") == str(tmp_path / "numba" / "atris-k")  # NUMBA_CACHE_DIR
    monkeypatch.setattr(jit.numba.config, "CACHE_DIR", "", raising=False)
    (tmp_path / "pkg").mkdir()
    assert jit.cache_dir(tmp_path / "pkg", "k") == str(tmp_path / "pkg" / "__pycache__" / "numba-k")


def test_the_kernel_cache_is_keyed_on_every_kernel_module(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """numba keys a cached kernel on its own source file, and a kernel inlines helpers from
    other modules: the rival test's kernels kept the visibility prior's old count after
    identity_kernels.py changed, until the cache was deleted. The cache directory is
    named after every kernel module's source: a change in any of them (not elsewhere)
    moves it, under NUMBA_CACHE_DIR when set, else the package's __pycache__. Checked:
    with source_key hashing the file names only, this test failed."""
    from atris_node import jit

    package = tmp_path / "pkg"
    for folder, name in (("pipeline", "a_kernels.py"), ("sim", "b_kernels.py"),
                         ("cli", "c.py")):
        (package / folder).mkdir(parents=True)
        (package / folder / name).write_text("x = 1\n")
    key = jit.source_key(package)
    (package / "cli" / "c.py").write_text("x = 2\n")
    assert jit.source_key(package) == key  # no kernels there
    (package / "pipeline" / "a_kernels.py").write_text("x = 2\n")
    changed = jit.source_key(package)
    assert changed != key
    (package / "sim" / "b_kernels.py").write_text("x = 2\n")
    assert jit.source_key(package) not in (key, changed)
    monkeypatch.setattr(jit.numba.config, "CACHE_DIR", str(tmp_path / "numba"), raising=False)
    assert jit.cache_dir(package, key) == str(tmp_path / "numba" / f"atris-{key}")
    monkeypatch.setattr(jit.numba.config, "CACHE_DIR", "", raising=False)
    assert jit.cache_dir(package, key) == str(package / "__pycache__" / f"numba-{key}")
