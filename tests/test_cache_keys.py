"""A cache key is everything the result depends on (issue 32 item 1).

The cached front end (:mod:`phc.codegen.fastpath`) keys a record on every file the compilation
read *or tried to read*, by the path as written and resolved with the symbolic links on
the way; the signed compiled-function files (:mod:`phc.codegen.numba_cache`) are tied to
their names; special files in the state and cache directories are refused without
blocking; a cache problem is never blamed on the model or called a phc bug.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from phc.codegen import fastpath
from phc.cli import main
from model_texts import GEAR_PART, USES_GEAR  # a nested gear stage and a model that uses it
from time_limits import SUBPROCESS_TIMEOUT

REPO = Path(__file__).resolve().parents[1]
PENDULUM = (REPO / "models" / "pendulum.yaml").read_text(encoding="utf-8")
MSD = (REPO / "models" / "mass_spring_damper.yaml").read_text(encoding="utf-8")
RUN = ["--t-end", "0.5", "--n-out", "11", "--quiet"]


USES_PARTS_GEAR = USES_GEAR.replace("file: gear.yaml", "file: parts/gear.yaml")


@pytest.fixture()
def cache(tmp_path, monkeypatch):
    """A private cache and key of this test's own."""
    monkeypatch.setenv("PHC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("PHC_STATE_DIR", str(tmp_path / "state"))
    monkeypatch.delenv(fastpath.ENV_SWITCH, raising=False)
    return tmp_path / "cache"


def _last_p(csv: Path) -> float:
    return float(np.genfromtxt(csv, delimiter=",", names=True)["outputp"][-1])


# ---------------------------------------------------------------------------------------
# a repointed symbolic link


@pytest.mark.parametrize("link", ["file", "directory"])
def test_a_repointed_symbolic_link_runs_the_new_model(tmp_path, cache, monkeypatch, link):
    """`parts/gear.yaml -> gear_v1.yaml` repointed at a version with another ratio (or the
    directory `parts -> parts_v1` at `parts_v2`): the old target did not change, yet the
    model did; the cached front end must not run the old one."""
    if link == "file":
        parts = tmp_path / "parts"
        parts.mkdir()
        (parts / "gear_v1.yaml").write_text(GEAR_PART, encoding="utf-8")
        (parts / "gear_v2.yaml").write_text(GEAR_PART.replace("N: 3.0", "N: 5.0"), encoding="utf-8")
        (parts / "gear.yaml").symlink_to("gear_v1.yaml")
    else:
        for version, ratio in (("parts_v1", "3.0"), ("parts_v2", "5.0")):
            (tmp_path / version).mkdir()
            (tmp_path / version / "gear.yaml").write_text(GEAR_PART.replace("N: 3.0", f"N: {ratio}"),
                                                          encoding="utf-8")
        (tmp_path / "parts").symlink_to("parts_v1")
    model = tmp_path / "geared.yaml"
    model.write_text(USES_PARTS_GEAR, encoding="utf-8")
    assert main(["simulate", str(model), "--out", str(tmp_path / "a.csv"), *RUN]) == 0
    assert main(["simulate", str(model), "--out", str(tmp_path / "a2.csv"), *RUN]) == 0  # from the cache

    repointed = tmp_path / "parts" / "gear.yaml" if link == "file" else tmp_path / "parts"
    repointed.unlink()
    repointed.symlink_to("gear_v2.yaml" if link == "file" else "parts_v2")
    assert main(["simulate", str(model), "--out", str(tmp_path / "b.csv"), *RUN]) == 0
    monkeypatch.setenv(fastpath.ENV_SWITCH, "0")
    assert main(["simulate", str(model), "--out", str(tmp_path / "fresh.csv"), *RUN]) == 0
    assert _last_p(tmp_path / "b.csv") == _last_p(tmp_path / "fresh.csv")
    assert _last_p(tmp_path / "b.csv") != pytest.approx(_last_p(tmp_path / "a.csv"), rel=1e-3)


# ---------------------------------------------------------------------------------------
# a file that was missing (or refused) is looked at again


def _msd_scene(tmp_path: Path) -> Path:
    (tmp_path / "msd_model.yaml").write_text(MSD, encoding="utf-8")
    path = tmp_path / "msd.yaml"
    path.write_text("format_version: 1\nmodel: msd_model.yaml\nname: msd\nt_end: 5.0\nn_out: 51\n"
                    "outputs: {x: spring.x, v: mass.p}\nreference_values: {file: ref.csv}\n", encoding="utf-8")
    return path


def _make(path: Path, what: str) -> None:
    if path.exists() or path.is_symlink():
        path.unlink()
    if what == "fifo":
        os.mkfifo(path)
    elif what == "valid":
        path.write_text("t,x\n1.0,0.1\n2.0,0.2\n", encoding="utf-8")
    elif what == "wrong column":
        path.write_text("t,nonesuch\n1.0,0.1\n", encoding="utf-8")
    else:
        assert what == "missing"


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
@pytest.mark.parametrize("before, after", [("missing", "valid"), ("missing", "wrong column"), ("missing", "fifo"),
                                           ("fifo", "valid"), ("fifo", "missing")])
def test_a_fixed_file_does_not_keep_its_old_error(tmp_path, cache, capsys, before, after):
    scene = _msd_scene(tmp_path)
    ref = tmp_path / "ref.csv"
    _make(ref, before)

    def printed() -> str:
        out = capsys.readouterr()
        return out.out + out.err

    first = main(["validate", str(scene)])
    old = printed()
    assert first == 1 and "[PHC-E607]" in old, old
    assert main(["validate", str(scene)]) == 1  # the same result (from the cache)
    assert printed() == old
    _make(ref, after)
    code = main(["validate", str(scene)])
    new = printed()
    if after == "valid":
        assert code == 0 and "ok (" in new, new
    else:
        assert code == 1 and new != old, new
        assert {"wrong column": "nonesuch", "fifo": "FIFO", "missing": "not found"}[after] in new


# ---------------------------------------------------------------------------------------
# special files in the state and cache directories


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
@pytest.mark.parametrize("command", ["simulate", "validate"])
def test_a_fifo_named_cache_key_does_not_hang(tmp_path, command):
    """A FIFO where the signing key belongs: refused without opening it for a blocking read.
    (The timeout only keeps a regression from hanging the test suite.)"""
    state = tmp_path / "state"
    state.mkdir(mode=0o700)
    os.mkfifo(state / "cache-key", 0o600)
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    env = dict(os.environ, PHC_CACHE_DIR=str(tmp_path / "cache"), PHC_STATE_DIR=str(state),
               PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.pop(fastpath.ENV_SWITCH, None)
    argv = [sys.executable, "-m", "phc", command, str(model)]
    if command == "simulate":
        argv += ["--out", str(tmp_path / "a.csv"), *RUN]
    try:
        done = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=240, cwd=tmp_path)
    except subprocess.TimeoutExpired:
        pytest.fail(f"phc {command} blocked on a FIFO named cache-key")
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_fifos_in_the_cache_are_refused_without_blocking(tmp_path):
    """A FIFO where a signing key, a compiled-function file or a front-end record belongs:
    every reader of phc's state and cache returns nothing at once."""
    fifo = tmp_path / "cache-key"
    os.mkfifo(fifo, 0o600)
    code = ("import sys\nfrom phc.codegen.load import read_key\nfrom phc.codegen.numba_cache import _read_private\n"
            "from phc.codegen.fastpath import _read_regular\n"
            "print(read_key(sys.argv[1]), _read_private(sys.argv[1]), _read_regular(sys.argv[1], 100))\n")
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    try:
        done = subprocess.run([sys.executable, "-c", code, str(fifo)], capture_output=True, text=True, env=env,
                              timeout=SUBPROCESS_TIMEOUT)
    except subprocess.TimeoutExpired:
        pytest.fail("a reader of phc's cache blocked on a FIFO")
    assert done.stdout.strip() == "None None None", done.stdout + done.stderr


def test_a_cache_under_a_directory_others_may_write_is_refused(tmp_path, monkeypatch):
    """Only the last path component used to be checked: a cache directory inside a directory
    anyone may write (and rename entries of) could be swapped for a link between the check
    and the write. Every directory on the way must be safe (a sticky one such as /tmp is)."""
    from phc.codegen import load

    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o777)  # world-writable, not sticky
    monkeypatch.setenv("PHC_CACHE_DIR", str(shared / "phc"))
    monkeypatch.setattr(load, "_PRIVATE_FALLBACK", None)
    with pytest.warns(load.CacheWarning, match="writable by other users"):
        _, path = load.load_generated("VALUE = 1\n")
    assert not str(path).startswith(str(shared))
    sticky = tmp_path / "sticky"
    sticky.mkdir()
    sticky.chmod(0o1777)  # as /tmp: others cannot rename what is ours
    monkeypatch.setenv("PHC_CACHE_DIR", str(sticky / "phc"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, path = load.load_generated("VALUE = 2\n")
    assert path.parent == sticky / "phc"


# ---------------------------------------------------------------------------------------
# signed compiled functions are tied to their names


def _numba_ready():
    pytest.importorskip("numba")
    from phc.codegen import numba_cache

    ok, why = numba_cache.available()
    if not ok:
        pytest.skip(why)
    return numba_cache


@pytest.mark.parametrize("source, target, suffixes", [("energy_scale", "hamiltonian", (".nbi", ".1.nbc")),
                                                       ("powers", "outputs", (".1.nbc",))],
                         ids=["index-and-data", "data"])
def test_a_signed_file_copied_over_another_name_is_a_miss(tmp_path, cache, monkeypatch, source, target, suffixes):
    """`energy_scale`'s signed files copied over `hamiltonian`'s loaded the wrong function
    (the energy certificate then blamed the model); `powers`' data file over `outputs`'
    was loaded as `outputs` (an internal reshape error). Now each is a miss with one
    warning, the function is compiled again and the model certifies."""
    numba_cache = _numba_ready()
    import phc
    from phc.errors import CacheWarning

    monkeypatch.setattr(numba_cache, "_LOADED", {})
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    phc.compile_model(model, certify=False, backend="numba")
    folder = cache / "numba"
    for suffix in suffixes:
        (src,) = folder.glob(f"*.{source}-*{suffix}")
        (dst,) = folder.glob(f"*.{target}-*{suffix}")
        shutil.copyfile(src, dst)
    numba_cache._LOADED.clear()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        compiled = phc.compile_model(model, backend="numba")  # certified: raises if the model is blamed
    module, ref = compiled.module, compiled.module.REFERENCE
    y = np.linspace(0.2, 0.8, ref.N)
    p = np.asarray(ref.full_parameters(), dtype=float)
    if target == "hamiltonian":
        assert module.hamiltonian(0.1, y, p) == pytest.approx(ref.hamiltonian(0.1, y, p), rel=1e-12)
    else:
        np.testing.assert_allclose(module.outputs(0.1, y, 0 * y, p), ref.outputs(0.1, y, 0 * y, p), rtol=1e-12)
    assert module.COMPILE_REPORT.misses >= 1  # compiled again
    cache_warnings = [w for w in caught if issubclass(w.category, CacheWarning)]
    assert len(cache_warnings) == 1, [str(w.message) for w in caught]
    assert "phc bug" not in str(cache_warnings[0].message)


def test_functions_from_the_cache_that_disagree_are_a_cache_problem_not_a_phc_bug(tmp_path, cache, monkeypatch):
    """Signed functions that disagree with the model (a race between two writers, a restored
    cache): compiled again without the cache, with one warning naming the cache."""
    numba_cache = _numba_ready()
    import phc
    from phc.codegen import numba_backend
    from phc.errors import CacheWarning

    monkeypatch.setattr(numba_cache, "_LOADED", {})
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    phc.compile_model(model, certify=False, backend="numba")
    numba_cache._LOADED.clear()
    real = numba_backend._cross_check

    def disagree_when_loaded(module, reference):  # what functions signed under a wrong name did
        return "residual entry 0: compiled 1.0, reference 0.0" if module.COMPILE_REPORT.hits else real(module,
                                                                                                          reference)

    monkeypatch.setattr(numba_backend, "_cross_check", disagree_when_loaded)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        compiled = phc.compile_model(model, certify=False, backend="numba")
    messages = [str(w.message) for w in caught]
    assert compiled.backend == "numba", messages  # compiled again, not the NumPy fallback
    assert not any("phc bug" in m for m in messages), messages
    assert sum(issubclass(w.category, CacheWarning) for w in caught) == 1, messages


def test_a_cache_directory_that_turns_unsafe_meanwhile_costs_the_saved_copy_not_the_backend(tmp_path, cache,
                                                                                            monkeypatch):
    """The cache directory passes phc's check, then is found unsafe when numba saves a
    function (a race: someone loosened it meanwhile). The functions are still compiled
    and run; one warning names the cache; nothing says "phc bug"."""
    numba_cache = _numba_ready()
    import phc
    from phc.errors import CacheWarning

    monkeypatch.setattr(numba_cache, "_LOADED", {})
    monkeypatch.setattr(numba_cache, "_WARNED", set(), raising=False)
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    # phc's check before compiling passes; numba's cache locator checks the directory again at
    # each save and now finds it unsafe
    (locator,) = numba_cache._cache_classes()[0]._impl_class._locator_classes

    def unsafe(self):
        raise OSError("is writable by other users (mode 777)")

    monkeypatch.setattr(locator, "ensure_cache_path", unsafe)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        compiled = phc.compile_model(model, certify=False, backend="numba")
    messages = [str(w.message) for w in caught]
    assert compiled.backend == "numba", messages
    assert not any("phc bug" in m for m in messages), messages
    assert sum(issubclass(w.category, CacheWarning) for w in caught) == 1, messages


def test_environment_that_changes_compilation_is_part_of_the_key(tmp_path, cache, monkeypatch):
    """`PHC_*` and numba's own `NUMBA_*` settings: a changed one is a miss."""
    from phc.cli import build_parser

    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    argv = ["simulate", str(model), "--out", str(tmp_path / "a.csv"), *RUN]
    monkeypatch.delenv("NUMBA_OPT", raising=False)
    assert main(argv) == 0

    def hit() -> bool:
        return fastpath.lookup(build_parser().parse_args(argv), {}) is not None

    assert hit()
    monkeypatch.setenv("NUMBA_OPT", "0")
    assert not hit()
    monkeypatch.delenv("NUMBA_OPT")
    assert hit()
