"""Where ident-opt keeps what it can rebuild: compiled regressors, simulated trials.

`cache_root` is `$IDENT_OPT_CACHE` when set, else `.cache` of the project holding a file (the nearest folder
above it with a `pyproject.toml`), else `.cache` next to the file. Each user of the cache keys its entries by
a hash of everything they depend on, so a stale entry is never reused.
"""

from __future__ import annotations

import os
from pathlib import Path


def cache_root(path: Path) -> Path:
    """The cache folder for a file (a problem, a URDF): $IDENT_OPT_CACHE if set, else `.cache` of the project
    holding it (the nearest folder above with a pyproject.toml), else `.cache` next to it."""
    env = os.environ.get("IDENT_OPT_CACHE")
    if env:
        return Path(env)
    here = Path(path).resolve().parent
    for folder in (here, *here.parents):
        if (folder / "pyproject.toml").is_file():
            return folder / ".cache"
    return here / ".cache"
