"""pint's parsed unit definitions, kept in phc's signed cache.

Building pint's UnitRegistry parses its definitions file (about 0.3 of its 0.4 s CPU). pint
keeps the parsed result on disk when given a `cache_folder` (its public option), as pickles,
which pint loads without any check. phc therefore keeps them as one bundle in its own cache
(`units/`), signed with the key of its compiled artefacts (phc.codegen.numba_cache), and
hands pint a private temporary copy of a bundle that verifies: a damaged, foreign or stale
bundle is a miss (the registry is built from the definitions and the bundle written again),
never an error. :func:`phc.frontend.units._registry` is the one caller.
"""

from __future__ import annotations

import re
from typing import Mapping, Optional

_BUNDLE_MAGIC = b"phc-pint-1\n"
_BUNDLE_FILES = 64
"""At most this many files in a bundle (pint writes three)."""


def _bundle_path(pint):
    """(the bundle's path, the signing key), or (None, None) where the configured cache
    directory or the key cannot be used: then pint parses its file, without a warning (the
    compiled back ends say what is wrong with the cache where they use it)."""
    import os

    from phc.codegen.load import _problem, configured_cache_dir
    from phc.codegen.numba_cache import signed_cache_dir

    root = configured_cache_dir()
    if os.path.lexists(root) and _problem(root):  # nothing is created inside a directory phc refuses
        return None, None
    folder, key, _ = signed_cache_dir(root / "units")
    if folder is None:
        return None, None
    return folder / f"pint-{pint.__version__}.bundle", key


def _pack(files: Mapping[str, bytes]) -> bytes:
    out = [_BUNDLE_MAGIC]
    for name in sorted(files):
        raw = name.encode("utf-8")
        out += [len(raw).to_bytes(2, "big"), raw, len(files[name]).to_bytes(8, "big"), files[name]]
    return b"".join(out)


def _unpack(payload: bytes) -> Optional[dict]:
    """The files of a bundle, or None when it is malformed or names a file outside its folder."""
    if not payload.startswith(_BUNDLE_MAGIC):
        return None
    files, at = {}, len(_BUNDLE_MAGIC)
    while at < len(payload):
        if len(files) >= _BUNDLE_FILES or at + 2 > len(payload):
            return None
        size = int.from_bytes(payload[at:at + 2], "big")
        name = payload[at + 2:at + 2 + size].decode("utf-8", "replace")
        at += 2 + size
        if at + 8 > len(payload) or not re.fullmatch(r"[A-Za-z0-9_.-]{1,128}", name) or name.startswith("."):
            return None
        size = int.from_bytes(payload[at:at + 8], "big")
        if at + 8 + size > len(payload):
            return None
        files[name] = payload[at + 8:at + 8 + size]
        at += 8 + size
    return files


def _read_bundle(path, key) -> Optional[dict]:
    from phc.codegen.numba_cache import _read_private, _verified

    data = _read_private(str(path))
    payload = _verified(key, data, path.name) if data is not None else None
    return _unpack(payload) if payload is not None else None


def _folder_files(folder) -> dict:
    import os

    return {name: (folder / name).read_bytes() for name in sorted(os.listdir(folder))
            if (folder / name).is_file()}


def cached_registry(pint):
    """``pint.UnitRegistry()``, its parsed definitions read from phc's signed cache where a
    bundle verifies, and written there where none does (see above)."""
    import shutil
    import tempfile
    from pathlib import Path

    try:
        path, key = _bundle_path(pint)
    except OSError:
        path = key = None
    if path is None:  # no usable cache directory or key: pint parses its file, as before
        return pint.UnitRegistry()
    files = _read_bundle(path, key)
    try:
        scratch = Path(tempfile.mkdtemp(prefix="phc-pint-"))  # mode 0700, ours
    except OSError:
        return pint.UnitRegistry()
    try:
        try:
            for name, data in (files or {}).items():
                (scratch / name).write_bytes(data)
        except OSError:
            shutil.rmtree(scratch, ignore_errors=True)
            return pint.UnitRegistry()
        try:
            ureg = pint.UnitRegistry(cache_folder=scratch)
        except Exception:  # noqa: BLE001 — pint refusing its own cache: parse the file, and
            try:  # drop the bundle, so that the next process writes it again
                path.unlink()
            except OSError:
                pass
            return pint.UnitRegistry()
        try:
            now = _folder_files(scratch)
        except OSError:
            return ureg
        if now != files:  # no bundle, or pint wrote other files: store what pint wrote
            _store_bundle(path, key, now)
        return ureg
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _store_bundle(path, key, files: Mapping[str, bytes]) -> None:
    import warnings

    from phc.codegen.load import enforce_cap, write_atomic
    from phc.codegen.numba_cache import _signed
    from phc.errors import CacheWarning

    if not files or len(files) > _BUNDLE_FILES or _unpack(_pack(files)) != dict(files):
        return
    try:
        if path.is_symlink():
            path.unlink()
        write_atomic(path, _signed(key, _pack(files), path.name))
        enforce_cap()
    except OSError as err:  # a full or read-only disk costs the cached copy, not the run
        warnings.warn(f"could not write pint's parsed unit definitions to {path.parent}: {err.strerror or err}",
                      CacheWarning, stacklevel=4)
