"""Load generated residual modules, cached on disk by content hash.

The module text is written to ``$PHC_CACHE_DIR`` (default ``~/.cache/phc``) under the
SHA-256 of its source and imported with :mod:`importlib`, so recompiling an unchanged
model reuses the file and the generated code can be inspected or imported on its own.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import tempfile
from pathlib import Path
from types import ModuleType


def cache_dir() -> Path:
    root = os.environ.get("PHC_CACHE_DIR")
    path = Path(root) if root else Path.home() / ".cache" / "phc"
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / ".probe"
        probe.touch()
    except OSError:
        path = Path(tempfile.gettempdir()) / "phc-cache"
        path.mkdir(parents=True, exist_ok=True)
    return path


def source_hash(source: str) -> str:
    return hashlib.sha256(source.encode()).hexdigest()[:20]


def load_generated(source: str, name: str = "model") -> tuple[ModuleType, Path]:
    """Write (if new) and import the generated module; returns (module, path)."""
    digest = source_hash(source)
    path = cache_dir() / f"phc_{digest}.py"
    if not path.exists() or path.read_text() != source:
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(source)
        os.replace(tmp, path)
    spec = importlib.util.spec_from_file_location(f"phc_generated_{digest}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module, path
