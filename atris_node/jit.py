"""numba's ``njit`` as the node's kernels use it: nopython, the GIL released, and cached on
disk where numba can write a cache.

numba looks for a writable cache directory in ``NUMBA_CACHE_DIR``, the module's
``__pycache__`` and the user's cache directory, and refuses to decorate a cached function
when it finds none (a read-only install run by a user without a home directory). Here the
same directories are tried first: without one, the kernels are compiled at every start
instead (about 20 s) rather than failing. The systemd unit in ``launch/`` gives the node a
cache directory.

numba keys a cached kernel on its own source file only, and a kernel inlines the helpers
it calls from other modules: after a helper changed in place (``git pull``), an unchanged
module's kernel would load the old helper from the cache, silently (a test caught one:
the rival test's kernels kept the visibility prior's old count). So the cache lives in a
directory named after a digest of every kernel module's source (:func:`source_key`):
``numba-<key>`` in the package's ``__pycache__``, else ``atris-<key>`` in the user's
numba cache directory, or in ``NUMBA_CACHE_DIR`` when that is set.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numba
from numba.misc.appdirs import AppDirs


def _writable(path: str) -> bool:
    try:
        os.makedirs(path, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
    except OSError:
        return False
    return True


#: the package folders whose modules hold kernels (numba's compiled functions)
KERNEL_FOLDERS = ("pipeline", "sim", "demod")


def source_key(package: Path) -> str:
    """12 hex digits of the SHA-256 of this module's and every kernel folder's Python
    sources (names and contents, in path order) under ``package``."""
    digest = hashlib.sha256()
    sources = sorted(f for folder in KERNEL_FOLDERS for f in (package / folder).glob("*.py"))
    for f in (Path(__file__), *sources):
        digest.update(f.name.encode())
        digest.update(f.read_bytes())
    return digest.hexdigest()[:12]


def cache_dir(package: Path, key: str) -> str:
    """The directory the kernels are cached in for the sources ``key``: under
    ``NUMBA_CACHE_DIR`` when set, else the package's ``__pycache__``, else the user's
    numba cache directory; "" when none of them can be written (no cache)."""
    configured = getattr(numba.config, "CACHE_DIR", "")  # NUMBA_CACHE_DIR
    if configured:
        candidates = [os.path.join(configured, f"atris-{key}")]
    else:
        candidates = [os.path.join(package, "__pycache__", f"numba-{key}"),
                      os.path.join(AppDirs(appname="numba", appauthor=False).user_cache_dir,
                                   f"atris-{key}")]
    return next((path for path in candidates if _writable(path)), "")


_PACKAGE = Path(__file__).resolve().parent
#: where the kernels are cached ("" when nowhere); numba's cache locator reads it from
#: its config when a kernel is decorated (every kernel module imports this one first)
CACHE_DIR = cache_dir(_PACKAGE, source_key(_PACKAGE))
if CACHE_DIR:
    numba.config.CACHE_DIR = CACHE_DIR  # type: ignore[attr-defined]
#: whether the kernels are cached on disk
CACHE = bool(CACHE_DIR)


def kernel(signatures: Any = None) -> Callable[[Any], Any]:
    """``numba.njit`` with the node's options; ``signatures`` (a signature string, a numba
    type or a list of them) compiles at import instead of at the first call."""
    if signatures is None:
        return numba.njit(cache=CACHE, nogil=True)
    return numba.njit(signatures, cache=CACHE, nogil=True)


#: ``numba.njit`` for a helper that neither allocates nor keeps an array, compiled without
#: reference counting (numba's ``_nrt=False``): a counted call increments and decrements
#: the count of each of its array arguments (atomic operations), which cost as much as a
#: short helper's work when it is called per column or per peak
_UNCOUNTED: dict[str, Any] = {"_nrt": False, "cache": CACHE, "nogil": True}
uncounted = numba.njit(**_UNCOUNTED)
