"""fnsi: frequency-domain nonlinear subspace identification and its simulators.

Numba's on-disk cache of a compiled function is invalidated only when that function's
own source file changes, not when a kernel it inlines from another module does (the
integrators in :mod:`fnsi.newmark` and :mod:`fnsi.simulation` call the force kernels of
:mod:`fnsi.nonlinear`). A stale cache would silently compute old force laws, so unless
the user chose ``NUMBA_CACHE_DIR`` the cache lives in a directory named after a digest
of every numba source of the package.
"""

import hashlib
import os
from pathlib import Path

_NUMBA_SOURCES = ("nonlinear.py", "newmark.py", "simulation.py", "refinement.py")


def _numba_cache_dir() -> str:
    """Per-source-version cache directory under the user's cache home."""
    here = Path(__file__).parent
    digest = hashlib.sha256(b"".join((here / name).read_bytes() for name in _NUMBA_SOURCES))
    home = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    return str(home / "fnsi" / f"numba-{digest.hexdigest()[:16]}")


os.environ.setdefault("NUMBA_CACHE_DIR", _numba_cache_dir())
