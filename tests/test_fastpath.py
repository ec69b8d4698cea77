"""The cached front end of `phc simulate` (phc.codegen.fastpath): a hit runs the same simulation
as the full path, and anything that could make it stale is a miss."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from phc.codegen import fastpath
from phc.cli import build_parser, main
from phc.errors import CacheWarning
from model_texts import GEAR_PART, USES_GEAR  # a nested gear stage and a model that uses it
from time_limits import SUBPROCESS_TIMEOUT

REPO = Path(__file__).resolve().parents[1]

PENDULUM = (REPO / "models" / "pendulum.yaml").read_text(encoding="utf-8")


RUN = ["--t-end", "0.5", "--n-out", "11", "--quiet"]


@pytest.fixture()
def cache(tmp_path, monkeypatch):
    """A private cache and key of this test's own (nothing from other tests can hit)."""
    monkeypatch.setenv("PHC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("PHC_STATE_DIR", str(tmp_path / "state"))
    monkeypatch.delenv(fastpath.ENV_SWITCH, raising=False)
    return tmp_path / "cache" / fastpath.FOLDER


def simulate(model: Path, out: Path, *extra: str) -> int:
    return main(["simulate", str(model), "--out", str(out), *RUN, *extra])


def hit(model: Path, *extra: str) -> bool:
    """Whether `phc simulate model ...` would run from its cached front end."""
    args = build_parser().parse_args(["simulate", str(model), "--out", "x.csv", *RUN, *extra])
    params = dict(item.split("=", 1) for item in args.param or [])
    return fastpath.lookup(args, {k: float(v) for k, v in params.items()}) is not None


def test_a_hit_writes_the_same_csv_as_the_full_path(tmp_path, cache, capsys):
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    assert not hit(model)
    assert simulate(model, tmp_path / "full.csv") == 0
    assert len(list(cache.glob("*.json"))) == 1
    assert hit(model)
    full_out = capsys.readouterr().out
    assert simulate(model, tmp_path / "hit.csv") == 0
    hit_out = capsys.readouterr().out
    assert (tmp_path / "full.csv").read_bytes() == (tmp_path / "hit.csv").read_bytes()

    def steady(text):  # timings, memory and the file name differ from run to run
        return [line for line in text.splitlines() if not line.lstrip().startswith(("work", "memory", "compiled",
                                                                                      "wrote"))]
    assert steady(hit_out) == steady(full_out)
    assert "certified" in hit_out


def test_a_hit_imports_neither_sympy_nor_pint(tmp_path, cache):
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    assert simulate(model, tmp_path / "a.csv") == 0
    code = ("import sys\nfrom phc.cli import main\n"
            f"code = main(['simulate', {str(model)!r}, '--out', {str(tmp_path / 'b.csv')!r}, *{RUN!r}])\n"
            "print(code, sorted(m for m in ('sympy', 'pint', 'pydantic', 'phc.ir.dae', 'phc.frontend.elaborate') "
            "if m in sys.modules))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=dict(os.environ),
                          timeout=SUBPROCESS_TIMEOUT)
    assert done.stdout.strip().splitlines()[-1] == "0 []", done.stdout + done.stderr
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()


def test_editing_the_model_is_a_miss(tmp_path, cache):
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    assert simulate(model, tmp_path / "a.csv") == 0
    assert hit(model)
    model.write_text(PENDULUM.replace("L: {value: 1.0", "L: {value: 2.0"), encoding="utf-8")
    assert not hit(model)
    assert simulate(model, tmp_path / "b.csv") == 0
    x0 = np.genfromtxt(tmp_path / "b.csv", delimiter=",", names=True)["pendulumx"][0]
    assert x0 == 2.0  # the initial value `pendulum.x: L` of the edited model


def test_editing_a_referenced_file_is_a_miss(tmp_path, cache):
    (tmp_path / "gear.yaml").write_text(GEAR_PART, encoding="utf-8")
    model = tmp_path / "geared.yaml"
    model.write_text(USES_GEAR, encoding="utf-8")
    assert simulate(model, tmp_path / "a.csv") == 0
    assert hit(model)
    (tmp_path / "gear.yaml").write_text(GEAR_PART.replace("N: 3.0", "N: 5.0"), encoding="utf-8")
    assert not hit(model)
    assert simulate(model, tmp_path / "b.csv") == 0
    a = np.genfromtxt(tmp_path / "a.csv", delimiter=",", names=True)
    b = np.genfromtxt(tmp_path / "b.csv", delimiter=",", names=True)
    # a constant torque through the gear: p(t) = N·tau·t / (1 + 0) at the load (ideal transformer)
    ratio = b["outputp"][-1] / a["outputp"][-1]
    assert ratio == pytest.approx(5.0 / 3.0, rel=1e-6) or ratio == pytest.approx(3.0 / 5.0, rel=1e-6)


def test_a_param_an_initial_value_is_written_in_takes_the_full_path(tmp_path, cache):
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    assert simulate(model, tmp_path / "a.csv") == 0
    assert not hit(model, "--param", "L=2")  # `pendulum.x: L`
    assert simulate(model, tmp_path / "b.csv", "--param", "L=2") == 0
    b = np.genfromtxt(tmp_path / "b.csv", delimiter=",", names=True)
    assert b["pendulumx"][0] == 2.0
    # a parameter no initial value uses: the cached front end, the same numbers as the full path
    assert hit(model, "--param", "g=5")
    assert simulate(model, tmp_path / "c.csv", "--param", "g=5") == 0
    os.environ[fastpath.ENV_SWITCH] = "0"
    try:
        assert not hit(model, "--param", "g=5")
        assert simulate(model, tmp_path / "d.csv", "--param", "g=5") == 0
    finally:
        del os.environ[fastpath.ENV_SWITCH]
    assert (tmp_path / "c.csv").read_bytes() == (tmp_path / "d.csv").read_bytes()


@pytest.mark.parametrize("damage", ["garbage", "truncated", "resigned"])
def test_a_damaged_record_is_a_miss_with_one_warning(tmp_path, cache, capsys, damage):
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    assert simulate(model, tmp_path / "a.csv") == 0
    (record,) = cache.glob("*.json")
    data = record.read_bytes()
    if damage == "garbage":
        record.write_bytes(b"\x00not a record")
    elif damage == "truncated":
        record.write_bytes(data[: len(data) // 2])
    else:  # valid JSON, edited without the key: the signature no longer matches
        record.write_bytes(data.replace(b'"guess', b'"guesS', 1) if b'"guess' in data else data[:-1] + b" ")
    capsys.readouterr()
    with pytest.warns(CacheWarning, match="does not verify"):
        assert not hit(model)
    assert simulate(model, tmp_path / "b.csv") == 0
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err and "error" not in captured.err
    (line,) = [line for line in captured.err.splitlines() if "warning" in line]  # one warning, naming the cache
    assert line.startswith("phc: warning: cached front-end record ") and "phc bug" not in line
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()
    assert hit(model)  # the full path wrote a good record again


def test_options_that_need_the_model_take_the_full_path(tmp_path, cache):
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    assert simulate(model, tmp_path / "a.csv") == 0
    assert not hit(model, "--estimate-error")
    assert not hit(model, "--no-certify")  # a different compilation: its own record


def test_cache_clean_removes_the_records(tmp_path, cache, capsys):
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    assert simulate(model, tmp_path / "a.csv") == 0
    assert list(cache.glob("*.json"))
    assert main(["cache", "clean"]) == 0
    assert not list(cache.glob("*.json"))
    assert not hit(model)


def test_validate_from_the_cache_prints_what_the_full_path_printed(tmp_path, cache, capsys):
    good = tmp_path / "pendulum.yaml"
    good.write_text(PENDULUM, encoding="utf-8")
    bad = tmp_path / "bad.yaml"
    bad.write_text(PENDULUM.replace("    V: m*g*y", "    V: m*g*y\n    mass: 3"), encoding="utf-8")
    for fmt in ("text", "json"):
        argv = ["validate", "--format", fmt, str(good), str(bad)]
        assert main(argv) == 1
        full = capsys.readouterr()
        assert all(fastpath.lookup_validate(build_parser().parse_args(argv), str(p)) is not None for p in (good, bad))
        assert main(argv) == 1
        cached = capsys.readouterr()
        assert (cached.out, cached.err) == (full.out, full.err)
    assert "mass" in full.out  # the unknown key is reported, located
    good.write_text(PENDULUM.replace("L: {value: 1.0", "L: {value: 2.0"), encoding="utf-8")
    assert fastpath.lookup_validate(build_parser().parse_args(["validate", str(good)]), str(good)) is None


def test_validate_from_the_cache_imports_no_sympy(tmp_path, cache):
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    assert main(["validate", str(model)]) == 0
    code = ("import sys\nfrom phc.cli import main\n"
            f"code = main(['validate', {str(model)!r}])\n"
            "print(code, sorted(m for m in ('sympy', 'pint', 'pydantic', 'scipy', 'phc.ir.dae') if m in sys.modules))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=dict(os.environ),
                          timeout=SUBPROCESS_TIMEOUT)
    lines = done.stdout.strip().splitlines()
    assert lines[-1] == "0 []", done.stdout + done.stderr
    assert lines[0].endswith("ok (4 states, 7 equations, 7 unknowns)")


def test_a_hit_prints_the_same_json_summary(tmp_path, cache, capsys):
    import json

    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    runs = []
    for _ in range(2):
        assert main(["simulate", str(model), *RUN, "--format", "json"]) == 0
        runs.append(json.loads(capsys.readouterr().out))
    timed = {"cpu_time_s", "peak_memory_bytes", "compile_time_s", "timings"}
    full, cached = runs
    assert set(full) == set(cached)
    assert set(full["timings"]) == set(cached["timings"])  # the same phases, their own times
    assert {k: v for k, v in full.items() if k not in timed | {"compiled"}} == \
        {k: v for k, v in cached.items() if k not in timed | {"compiled"}}
    assert {k: v for k, v in full["compiled"].items() if k not in timed} == \
        {k: v for k, v in cached["compiled"].items() if k not in timed}


def _hit_in_fresh_process(model: Path, out: Path, backend: str, watched: tuple[str, ...]) -> list[str]:
    """The lines a fresh process prints for `phc simulate model --backend backend` from the
    record; the last is ``<exit code> <those of `watched` it imported> <numba imported>``."""
    code = ("import sys\nfrom phc.cli import main\n"
            f"code = main(['simulate', {str(model)!r}, '--out', {str(out)!r}, '--backend', {backend!r}, *{RUN!r}])\n"
            f"print(code, sorted(m for m in {watched!r} if m in sys.modules), 'numba' in sys.modules)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=dict(os.environ),
                          timeout=SUBPROCESS_TIMEOUT)
    lines = done.stdout.strip().splitlines() or [""]
    lines[-1] += "" if done.returncode == 0 else f"\n{done.stderr}"
    return lines


SYMBOLIC = ("sympy", "pint", "pydantic", "phc.ir.dae", "phc.frontend.elaborate")
"""What a hit must not import: the model language and the symbolic pipeline."""


def test_a_numba_hit_loads_the_compiled_functions_without_sympy(tmp_path, cache, capsys, monkeypatch):
    """On the compiled backend the record keeps the kernel text: a hit loads the model's
    compiled functions from their signed disk cache, imports neither sympy nor the model
    language nor the code that builds compiled functions, and writes the full path's CSV."""
    pytest.importorskip("numba")
    from phc.codegen import numba_cache

    monkeypatch.setattr(numba_cache, "_LOADED", {})  # compiled by an earlier test: not in this test's cache
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    assert simulate(model, tmp_path / "full.csv", "--backend", "numba") == 0
    assert "backend  numba: compiled functions (compiled and cached" in capsys.readouterr().out
    assert hit(model, "--backend", "numba") and not hit(model)  # the backend is part of the key
    lines = _hit_in_fresh_process(model, tmp_path / "hit.csv", "numba", SYMBOLIC + ("phc.codegen.numba_backend",))
    assert lines[-1] == "0 [] True", lines
    assert any("numba: compiled functions (loaded from the cache" in line for line in lines), lines
    assert (tmp_path / "full.csv").read_bytes() == (tmp_path / "hit.csv").read_bytes()


def test_a_c_hit_loads_the_library_without_sympy(tmp_path, cache, capsys, monkeypatch):
    """On the C back end the record keeps the C text: a hit loads the library from its
    signed cache, imports neither sympy nor the model language nor the C printer, and writes
    the full path's CSV."""
    from phc.codegen import c_backend, cc

    if not cc.available()[0]:
        pytest.skip("no C compiler")
    monkeypatch.setattr(c_backend, "_LOADED", {})  # built by an earlier test: not in this test's cache
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    assert simulate(model, tmp_path / "full.csv", "--backend", "c") == 0
    assert "backend  c: compiled functions" in capsys.readouterr().out
    assert hit(model, "--backend", "c") and not hit(model)  # the backend is part of the key
    lines = _hit_in_fresh_process(model, tmp_path / "hit.csv", "c", SYMBOLIC + ("phc.codegen.c_printer",))
    assert lines[-1].startswith("0 [] "), lines
    assert any("c: compiled functions (loaded from the cache" in line for line in lines), lines
    assert (tmp_path / "full.csv").read_bytes() == (tmp_path / "hit.csv").read_bytes()


def test_auto_runs_a_small_model_on_c_and_its_record_keeps_c(tmp_path, cache, capsys, monkeypatch):
    """Under `auto` a small model runs on C (the size rule is numba's only), short and long
    fixed-step runs alike; the cached run loads the same library and gives the same numbers."""
    from phc.codegen import backends, c_backend, cc

    if not cc.available()[0]:
        pytest.skip("no C compiler")
    monkeypatch.setattr(c_backend, "_LOADED", {})
    monkeypatch.setattr(backends, "AUTO_LOOP_STEPS", 200)
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    for t_end in ("0.1", "0.3"):
        first = _json_run(model, t_end, capsys)
        assert hit(model, "--t-end", t_end, *LONG)
        second = _json_run(model, t_end, capsys)
        for run in (first, second):
            assert (run["backend"], run["backend_note"]) == ("c", ""), run["backend_note"]
        same = ("steps", "n_residual_evals", "n_jacobian_evals", "energy_balance_error")
        assert {k: first[k] for k in same} == {k: second[k] for k in same}


def test_a_numba_record_whose_compiled_functions_are_gone_is_a_miss(tmp_path, cache, monkeypatch):
    """The compiled functions are evicted from their cache (or signed under another key):
    the record cannot compile them without the model's intermediate representation, so the
    lookup is a miss and the full path runs, with the same result."""
    pytest.importorskip("numba")
    import shutil

    from phc.codegen import numba_cache

    monkeypatch.setattr(numba_cache, "_LOADED", {})  # compiled by an earlier test: not in this test's cache
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    assert simulate(model, tmp_path / "full.csv", "--backend", "numba") == 0
    assert hit(model, "--backend", "numba")
    shutil.rmtree(cache.parent / "numba")
    numba_cache._LOADED.clear()  # what this process compiled
    assert not hit(model, "--backend", "numba")
    assert simulate(model, tmp_path / "again.csv", "--backend", "numba") == 0
    assert (tmp_path / "full.csv").read_bytes() == (tmp_path / "again.csv").read_bytes()
    assert hit(model, "--backend", "numba")  # the full path wrote the record and the functions again


LONG = ["--solver", "midpoint", "--step", "1e-3", "--n-out", "2", "--backend", "auto"]
"""A fixed-step run over one output interval: `--t-end` in ms is its number of steps."""


@pytest.fixture
def step_loop(monkeypatch):
    """The compiled step loop `auto` switches a long midpoint run of a small model to where C
    is not used (the C compiler made unavailable): numba's; the threshold lowered to 200 steps
    (short runs)."""
    from phc.codegen import backends, c_backend, cc, numba_backend, numba_cache

    if not numba_backend.available()[0]:
        pytest.skip("numba is not installed")
    monkeypatch.setattr(cc, "available", lambda: (False, "no C compiler found (test)"))
    monkeypatch.setattr(numba_cache, "_LOADED", {})  # compiled by an earlier test: not in this test's cache
    monkeypatch.setattr(c_backend, "_LOADED", {})
    monkeypatch.setattr(backends, "AUTO_LOOP_STEPS", 200)
    return "numba"


def _json_run(model: Path, t_end: str, capsys) -> dict:
    import json

    assert main(["simulate", str(model), "--quiet", "--format", "json", "--t-end", t_end, *LONG]) == 0
    return json.loads(capsys.readouterr().out)


def test_a_long_fixed_step_run_under_auto_runs_compiled_every_time(tmp_path, cache, capsys, step_loop):
    """`auto` runs a long fixed-step run of a small model on a compiled step loop
    (phc.codegen.backends.for_run): the record keeps what loads that module again (numba's
    kernel text), so the second, cached run of the same command switches too,
    runs the same compiled functions and gives the same numbers."""
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    first = _json_run(model, "0.3", capsys)
    assert hit(model, "--t-end", "0.3", *LONG)
    second = _json_run(model, "0.3", capsys)
    for run in (first, second):
        assert run["backend"] == step_loop, run["backend_note"]
        assert "auto: 300 midpoint steps" in run["backend_note"]
    assert "loaded from its description" not in second["backend_note"]
    same = ("steps", "n_residual_evals", "n_jacobian_evals", "energy_balance_error", "constraint_drift")
    assert {k: first[k] for k in same} == {k: second[k] for k in same}  # the same machine code, the same steps


def test_a_record_without_the_run_module_is_a_miss_for_a_long_run(tmp_path, cache, capsys, step_loop):
    """A record written by a short run (NumPy) keeps no compiled module: a long run of the
    same model is a miss, so the full path builds the module and switches; the record it
    writes then serves the long run."""
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    short = _json_run(model, "0.1", capsys)
    assert (short["backend"], short["backend_note"]) == ("numpy", "")
    assert hit(model, "--t-end", "0.1", *LONG) and not hit(model, "--t-end", "0.3", *LONG)
    assert _json_run(model, "0.3", capsys)["backend"] == step_loop
    assert hit(model, "--t-end", "0.3", *LONG) and hit(model, "--t-end", "0.1", *LONG)
    assert _json_run(model, "0.3", capsys)["backend"] == step_loop


def test_a_model_c_refuses_runs_from_its_record_on_numba(tmp_path, cache, capsys, monkeypatch):
    """`auto` tries C first, then numba (phc.codegen.backends.for_run). A model the C back
    end refuses runs on numba, and its record keeps numba's kernel: the cached run loads that
    one (it used to look for C only and miss every time)."""
    from phc.codegen import backends, c_backend, c_printer, numba_backend, numba_cache

    if not numba_backend.available()[0] or not c_backend.available()[0]:
        pytest.skip("needs numba and a C compiler")
    monkeypatch.setattr(numba_cache, "_LOADED", {})
    monkeypatch.setattr(c_backend, "_LOADED", {})
    monkeypatch.setattr(backends, "AUTO_LOOP_STEPS", 200)
    monkeypatch.setattr(c_printer, "unsupported", lambda expr, known: "a construct refused by this test")
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    first = _json_run(model, "0.3", capsys)
    assert first["backend"] == "numba", first["backend_note"]
    assert hit(model, "--t-end", "0.3", *LONG)
    second = _json_run(model, "0.3", capsys)
    assert second["backend"] == "numba", second["backend_note"]
    same = ("steps", "n_residual_evals", "n_jacobian_evals", "energy_balance_error")
    assert {k: first[k] for k in same} == {k: second[k] for k in same}


# ---------------------------------------------------------------------------------------
# phc compile


def compile_hit(model: Path, *extra: str) -> bool:
    """Whether `phc compile model ...` would write its files from the cached front end."""
    args = build_parser().parse_args(["compile", str(model), *extra])
    return fastpath.lookup_compile(args, str(model)) is not None


def _steady(text: str) -> list[str]:
    """Printed lines without what differs from run to run: the output directory and the seconds."""
    import re

    return [re.sub(r"\d+\.\d+ s\b", "<s>", re.sub(r"wrote \S+", "wrote <file>", line)) for line in text.splitlines()]


@pytest.mark.parametrize("backend", ["numpy", "c"])
def test_compile_from_the_cache_writes_the_same_files_and_lines(tmp_path, cache, capsys, monkeypatch, backend):
    """A second `phc compile` of an unchanged model writes the very bytes the full path
    wrote (the module, and on the C back end its C text) and prints the same lines; the
    certificate's verdict is the one the full path reached."""
    if backend == "c":
        from phc.codegen import c_backend, cc

        if not cc.available()[0]:
            pytest.skip("no C compiler")
        monkeypatch.setattr(c_backend, "_LOADED", {})  # built by an earlier test: not in this test's cache
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    assert not compile_hit(model, "--backend", backend)
    assert main(["compile", str(model), "--backend", backend, "-o", str(tmp_path / "full")]) == 0
    full = capsys.readouterr()
    assert compile_hit(model, "--backend", backend)
    assert not compile_hit(model, "--backend", backend, "--no-certify")  # another compilation: its own record
    if backend == "c":
        from phc.codegen import c_backend

        monkeypatch.setattr(c_backend, "_LOADED", {})  # as in a fresh process: from the signed cache
    assert main(["compile", str(model), "--backend", backend, "-o", str(tmp_path / "hit")]) == 0
    cached = capsys.readouterr()
    names = sorted(p.name for p in (tmp_path / "full").iterdir())
    assert names == sorted(p.name for p in (tmp_path / "hit").iterdir())
    assert ("pendulum.c" in names) == (backend == "c")
    for name in names:
        assert (tmp_path / "full" / name).read_bytes() == (tmp_path / "hit" / name).read_bytes(), name
    steady_full, steady_hit = _steady(full.out), _steady(cached.out)
    if backend == "c":  # the library: compiled by the full path, loaded from the signed cache by the hit
        assert "compiled and cached in" in full.out and "loaded from the cache in" in cached.out
        steady_full = [line.replace("compiled and cached in", "loaded from the cache in") for line in steady_full]
    assert steady_hit == steady_full
    assert "certified" in cached.out
    assert cached.err == full.err


def test_compile_from_the_cache_imports_no_sympy(tmp_path, cache):
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    assert main(["compile", str(model), "--backend", "numpy", "-o", str(tmp_path / "a")]) == 0
    code = ("import sys\nfrom phc.cli import main\n"
            f"code = main(['compile', {str(model)!r}, '--backend', 'numpy', '-o', {str(tmp_path / 'b')!r}])\n"
            f"print(code, sorted(m for m in {SYMBOLIC!r} if m in sys.modules))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=dict(os.environ),
                          timeout=SUBPROCESS_TIMEOUT)
    assert done.stdout.strip().splitlines()[-1] == "0 []", done.stdout + done.stderr
    assert (tmp_path / "a" / "pendulum.py").read_bytes() == (tmp_path / "b" / "pendulum.py").read_bytes()


def test_editing_a_compiled_model_is_a_miss(tmp_path, cache, capsys):
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    assert main(["compile", str(model), "--backend", "numpy", "-o", str(tmp_path / "a")]) == 0
    assert compile_hit(model, "--backend", "numpy")
    model.write_text(PENDULUM.replace("L: {value: 1.0", "L: {value: 2.0"), encoding="utf-8")
    assert not compile_hit(model, "--backend", "numpy")
    assert main(["compile", str(model), "--backend", "numpy", "-o", str(tmp_path / "b")]) == 0
    assert (tmp_path / "a" / "pendulum.py").read_bytes() != (tmp_path / "b" / "pendulum.py").read_bytes()
    assert compile_hit(model, "--backend", "numpy")  # the full path recorded the edited model


def test_compile_in_the_sarif_format_takes_the_full_path(tmp_path, cache, capsys):
    """The GitHub and SARIF formats report the diagnostics themselves, which a record keeps
    only as printed lines: they neither read nor write records."""
    model = tmp_path / "pendulum.yaml"
    model.write_text(PENDULUM, encoding="utf-8")
    assert main(["compile", str(model), "--backend", "numpy", "--format", "sarif", "-o", str(tmp_path / "a")]) == 0
    assert not compile_hit(model, "--backend", "numpy")
