"""numba's ``njit`` as the node's kernels use it: nopython, the GIL released, and cached on
disk where numba can write a cache.

numba looks for a writable cache directory in ``NUMBA_CACHE_DIR``, the module's
``__pycache__`` and the user's cache directory, and refuses to decorate a cached function
when it finds none (a read-only install run by a user without a home directory). Here the
same directories are tried first: without one, the kernels are compiled at every start
instead (about 20 s) rather than failing. The systemd unit in ``launch/`` gives the node a
cache directory.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
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


def can_cache(source_file: str) -> bool:
    """True when numba will find a writable cache directory for ``source_file``."""
    candidates = [os.path.join(os.path.dirname(source_file), "__pycache__"),
                  AppDirs(appname="numba", appauthor=False).user_cache_dir]
    configured = getattr(numba.config, "CACHE_DIR", "")  # NUMBA_CACHE_DIR
    if configured:
        candidates.insert(0, configured)
    return any(_writable(path) for path in candidates)


#: whether the kernels (all in ``atris_node/pipeline/``) are cached on disk
CACHE = can_cache(os.path.join(os.path.dirname(__file__), "pipeline", "__init__.py"))


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
