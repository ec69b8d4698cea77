"""pint's parsed unit definitions kept in phc's signed cache (phc.frontend.pint_cache.cached_registry).

Building pint's UnitRegistry parses its definitions file; pint's own `cache_folder` keeps
the parsed result as pickles, which pint loads unchecked. phc keeps them as one bundle
signed with the key of its compiled artefacts and hands pint a private copy of a bundle
that verifies. Here: the bundle is written once and then handed to pint unchanged; a
damaged, tampered or malformed bundle is a miss (rebuilt, never an error); the registry
built from it reads units as a registry built from the definitions does.
"""

from __future__ import annotations

import os

import pytest

pint = pytest.importorskip("pint")

from phc.frontend import pint_cache, units  # noqa: E402

UNITS = ["N/m", "mm", "kg*m^2", "rpm", "psi", "Ohm", "kN*m/rad", "m^3/s", "degC", "µF", "1"]


@pytest.fixture()
def cache(tmp_path, monkeypatch):
    """A private cache and signing key of this test's own; records what pint is handed."""
    monkeypatch.setenv("PHC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("PHC_STATE_DIR", str(tmp_path / "state"))
    calls = []
    real = pint.UnitRegistry

    def recording(*args, **kwargs):
        folder = kwargs.get("cache_folder")
        calls.append(sorted(os.listdir(folder)) if folder is not None else None)
        return real(*args, **kwargs)

    monkeypatch.setattr(pint, "UnitRegistry", recording)
    stored = []
    real_store = pint_cache._store_bundle
    monkeypatch.setattr(pint_cache, "_store_bundle", lambda *a: (stored.append(a[0]), real_store(*a)))
    return tmp_path / "cache" / "units", calls, stored


def _bundle(folder):
    found = list(folder.glob("pint-*.bundle"))
    assert len(found) == 1, found
    return found[0]


@pytest.fixture(scope="module")
def reference():
    """A registry pint parsed from its definitions file (no cache involved)."""
    return pint.UnitRegistry()


def _same_readings(ureg, reference) -> None:
    """`ureg` reads every unit of UNITS as a registry parsed from pint's file does."""
    for text in UNITS:
        if text == "Ohm":
            continue  # phc defines it on top (phc.frontend.units._registry)
        a = ureg.Quantity(1, ureg.parse_units(text.replace("µ", "u")))
        b = reference.Quantity(1, reference.parse_units(text.replace("µ", "u")))
        assert a._is_multiplicative == b._is_multiplicative, text
        if a._is_multiplicative:
            a, b = a.to_base_units(), b.to_base_units()
            assert str(a.units) == str(b.units), text
            assert a.magnitude == b.magnitude, text  # the same definitions: the same float


def test_written_once_then_handed_to_pint(reference, cache):
    folder, calls, stored = cache
    first = pint_cache.cached_registry(pint)
    bundle = _bundle(folder)
    data = bundle.read_bytes()
    assert calls == [[]] and len(stored) == 1  # nothing to hand over: pint parsed, phc stored
    second = pint_cache.cached_registry(pint)
    assert len(stored) == 1  # a hit writes nothing
    assert calls[1] and all(name.endswith((".pickle", ".json")) for name in calls[1])  # pint got the files
    assert bundle.read_bytes() == data
    _same_readings(first, reference)
    _same_readings(second, reference)


@pytest.mark.parametrize("damage", ["garbage", "flipped byte", "truncated", "empty"])
def test_a_damaged_bundle_is_rebuilt(reference, cache, damage):
    folder, calls, stored = cache
    pint_cache.cached_registry(pint)
    bundle = _bundle(folder)
    good = bundle.read_bytes()
    bad = {"garbage": b"not a bundle at all",
           "flipped byte": good[:-100] + bytes([good[-100] ^ 1]) + good[-99:],  # inside a pickle
           "truncated": good[: len(good) // 2],
           "empty": b""}[damage]
    bundle.write_bytes(bad)
    ureg = pint_cache.cached_registry(pint)
    assert calls[-1] == []  # the damaged bundle's files never reached pint
    assert len(stored) == 2 and bundle.read_bytes() == good  # written again, as before
    _same_readings(ureg, reference)
    pint_cache.cached_registry(pint)
    assert calls[-1] and len(stored) == 2  # and used from then on


def test_a_bundle_signed_under_another_key_is_not_used(cache, tmp_path, monkeypatch):
    folder, calls, stored = cache
    pint_cache.cached_registry(pint)
    monkeypatch.setenv("PHC_STATE_DIR", str(tmp_path / "other-state"))  # another user's key
    pint_cache.cached_registry(pint)
    assert calls[-1] == [] and len(stored) == 2


def test_a_bundle_names_only_plain_files():
    """A verified payload naming a path outside pint's folder, or holding too many files,
    is refused (the names become files in a temporary folder)."""
    good = {"a.pickle": b"x", "a.json": b"{}"}
    assert pint_cache._unpack(pint_cache._pack(good)) == good
    for name in ("../a.pickle", "sub/a.pickle", ".hidden", "", "a" * 200):
        assert pint_cache._unpack(pint_cache._pack({name: b"x"})) is None, name
    assert pint_cache._unpack(pint_cache._pack({f"f{k}": b"" for k in range(pint_cache._BUNDLE_FILES + 1)})) is None
    assert pint_cache._unpack(pint_cache._pack(good)[:-1]) is None  # a file shorter than its length
    assert pint_cache._unpack(b"phc-pint-0\n") is None


def test_the_bundle_is_part_of_the_cache(cache):
    """`phc cache info` counts it and `phc cache clean` removes it (then it is written again)."""
    from phc.codegen import load

    folder, calls, stored = cache
    pint_cache.cached_registry(pint)
    bundle = _bundle(folder)
    assert bundle in [p for _, _, p in load._entries(load.cache_dir())]
    files, _ = load.clean()
    assert files >= 1 and not bundle.exists()
    pint_cache.cached_registry(pint)
    assert calls[-1] == [] and bundle.exists()


def test_an_unusable_cache_directory_costs_the_cache_only(tmp_path, monkeypatch, reference):
    """A cache directory others may write: pint parses its file, nothing is written there,
    and no warning is added to the model's run."""
    import warnings

    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o777)
    monkeypatch.setenv("PHC_CACHE_DIR", str(shared))
    monkeypatch.setenv("PHC_STATE_DIR", str(tmp_path / "state"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ureg = pint_cache.cached_registry(pint)
    assert list(shared.iterdir()) == []
    _same_readings(ureg, reference)


def test_a_bundle_pint_cannot_read_is_dropped(cache, reference):
    """A bundle that verifies but whose pickles pint cannot load (written by phc itself from
    wrong bytes): the registry is parsed from pint's file and the bundle removed, so the
    next process writes a good one."""
    folder, calls, stored = cache
    pint_cache.cached_registry(pint)
    bundle = _bundle(folder)
    files = pint_cache._read_bundle(bundle, pint_cache._bundle_path(pint)[1])
    broken = {name: (b"\x80\x05not a pickle" if name.endswith(".pickle") else data) for name, data in files.items()}
    pint_cache._store_bundle(bundle, pint_cache._bundle_path(pint)[1], broken)
    assert pint_cache._read_bundle(bundle, pint_cache._bundle_path(pint)[1]) == broken  # it verifies
    ureg = pint_cache.cached_registry(pint)
    _same_readings(ureg, reference)
    assert not bundle.exists()
    pint_cache.cached_registry(pint)
    assert pint_cache._read_bundle(bundle, pint_cache._bundle_path(pint)[1]) == files  # written again
