"""Scale: structural passes over long chains must not recurse (issue "untrusted input",
item "scale breaks in the middle"): a string of 2 000 elements once ended in
`internal error: RecursionError` inside networkx's recursive Hopcroft–Karp."""

import inspect
import os
import random
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sps

import phc
from phc.analysis.matching import bipartite_matching
from phc.simulation.initial import DENSE_LIMIT, consistent_initial_conditions

MODELS = Path(__file__).resolve().parents[1] / "models"


CANTILEVER = """format_version: 1
name: cantilever
parameters: {EI: 68.27, rhoA: 0.50368, F: 1.0}
components:
  beam: {type: euler_bernoulli_beam, length: 0.3, elements: 400, rhoA: rhoA, EI: EI}
  clamp: {type: zero_flow, domain: mechanical.translational}
  clamp_rot: {type: zero_flow, domain: mechanical.rotational}
  load: {type: effort_source, domain: mechanical.translational, value: "F*sin(100*t)"}
  free_rot: {type: zero_effort, domain: mechanical.rotational}
connections:
  - [beam.a, clamp.port]
  - [beam.a_rot, clamp_rot.port]
  - [beam.b, load.port]
  - [beam.b_rot, free_rot.port]
"""
"""The cantilever of benchmarks/bench_beam_scale.py."""


def _chain(n: int, reverse: bool) -> sps.csr_matrix:
    """Row i touches columns i and i+1 (reversed: the augmenting paths run the whole chain)."""
    rows = np.r_[np.arange(n), np.arange(n - 1)]
    cols = np.r_[np.arange(n), np.arange(1, n)]
    if reverse:
        cols = n - 1 - cols
    return sps.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))


def _python_work(fn, *args, **kwargs) -> tuple[object, int]:
    """`fn`'s result and the Python work it did: the lines of Python code it executed
    (a loop's line counts once per pass) plus the calls it made, of Python and of builtin
    functions."""
    work = 0

    def trace(frame, event, arg):
        nonlocal work
        work += 1   # "call" and then every "line" of the frame
        return trace

    def profile(frame, event, arg):
        nonlocal work
        if event == "c_call":
            work += 1

    previous = sys.gettrace(), sys.getprofile()
    sys.settrace(trace)
    sys.setprofile(profile)
    try:
        result = fn(*args, **kwargs)
    finally:
        sys.settrace(previous[0])
        sys.setprofile(previous[1])
    return result, work


def test_matching_of_a_20000_chain_does_not_recurse(monkeypatch):
    """No recursion in the chain length, and no Python work per link either: the matching
    of 20 000 links executes no more Python lines and calls than that of 2 000 (one compiled
    maximum flow on a network of rows + nonzeros + columns edges does the work; counted,
    not timed)."""
    import scipy.sparse.csgraph as csgraph  # bipartite_matching imports maximum_flow from it when called

    flows = []   # edges of each maximum-flow network
    maximum_flow = csgraph.maximum_flow

    def counting_flow(network, *args, **kwargs):
        flows.append(network.nnz)
        return maximum_flow(network, *args, **kwargs)

    monkeypatch.setattr(csgraph, "maximum_flow", counting_flow)
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(200)  # anything recursive in the chain length would fail at once
    try:
        for reverse in (False, True):
            bipartite_matching(_chain(200, reverse), prefer_early=True)   # warm-up (first-call imports)
            _, small = _python_work(bipartite_matching, _chain(2_000, reverse), prefer_early=True)
            flows.clear()
            match, large = _python_work(bipartite_matching, _chain(20_000, reverse), prefer_early=True)
            assert large <= small + 50, (small, large)
            assert flows == [20_000 + 39_999 + 20_000]
            assert np.all(match >= 0) and len(set(match.tolist())) == 20_000
    finally:
        sys.setrecursionlimit(limit)


def test_structural_check_of_a_beam_finishes(tmp_path):
    """scipy's own maximum_bipartite_matching did not return on the structural pattern of
    a 125-element cantilever (no dead-end marking in its depth-first phase, scipy issue
    26147): run in a subprocess so that such a regression fails instead of hanging. The
    timeout only kills a hung process (about 2 s of CPU when it works); nothing is timed."""
    path = tmp_path / "cantilever.yaml"
    path.write_text(CANTILEVER)
    code = ("import sys; from phc.pipeline import build_dae; "
            "dae, d = build_dae(sys.argv[1]); assert dae is not None, d; print(len(dae.equations), len(dae.variables))")
    run = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=600,
                         env=dict(os.environ, PHC_CACHE_DIR=str(tmp_path / "cache")))
    assert run.returncode == 0, run.stderr[-2000:]
    equations, variables = map(int, run.stdout.split())
    assert equations == variables > 3000   # (3207) the whole 400-element beam was built and matched


def _greedy_basis(pattern: sps.csr_matrix) -> set[int]:
    """Reference: the lexicographically first set of matchable rows (rows in order, each
    kept when an augmenting path can add it) — the greedy basis of the transversal matroid."""
    m, n = pattern.shape
    row_of = [-1] * n
    kept = set()
    for u in range(m):
        parent, queue, k, end = {u: None}, [u], 0, None
        while k < len(queue) and end is None:
            r = queue[k]
            k += 1
            for c in pattern.indices[pattern.indptr[r]:pattern.indptr[r + 1]].tolist():
                if row_of[c] < 0:
                    end = (r, c)
                    break
                if row_of[c] not in parent:
                    parent[row_of[c]] = (r, c)
                    queue.append(row_of[c])
        if end is None:
            continue
        r, c = end
        while True:  # flip the path back to u: each row takes the column it was reached by
            row_of[c] = r
            if r == u:
                break
            r, c = parent[r]
        kept.add(u)
    return kept


def test_redundant_rows_reported_are_the_latest():
    rng = random.Random(4)
    for _ in range(60):
        m, n = rng.randint(1, 9), rng.randint(1, 9)
        dense = np.array([[rng.random() < 0.3 for _ in range(n)] for _ in range(m)], dtype=float)
        pattern = sps.csr_matrix(dense)
        match = bipartite_matching(pattern, prefer_early=True)
        rows = set(np.flatnonzero(match >= 0).tolist())
        cols = set(match[match >= 0].tolist())
        assert all(dense[i, match[i]] for i in rows)
        assert len(cols) == len(rows) == len(_greedy_basis(pattern))  # maximum
        assert rows == _greedy_basis(pattern)
        assert cols == _greedy_basis(sps.csr_matrix(dense.T))


def test_a_3000_element_string_gets_through_consistent_initialization(tmp_path, monkeypatch):
    """12 004 unknowns, initialized with a bounded amount of work (counted, not timed): a few
    Gauss–Newton steps, a number of model evaluations independent of the mesh (no finite
    difference per column), and no dense matrix beyond DENSE_LIMIT."""
    # without the output `energy: H` (not what this test is about; tests/codegen/test_output_energy.py)
    text = (MODELS / "vibrating_string.yaml").read_text().replace("elements: 16", "elements: 3000")
    text = "\n".join(line for line in text.splitlines() if not line.strip().startswith("energy: H"))
    path = tmp_path / "string3000.yaml"
    path.write_text(text)
    kwargs = {"certify": False} if "certify" in inspect.signature(phc.compile_model).parameters else {}
    mod = phc.compile_model(path, **kwargs).module
    p = mod.full_parameters()
    n = mod.N
    dif = np.flatnonzero(np.asarray(mod.DIFFERENTIAL))
    evaluations = {"residual": 0, "jacobian": 0, "hamiltonian": 0}
    for name in evaluations:
        if hasattr(mod, name):
            def counting(*args, _f=getattr(mod, name), _name=name, **kwargs):
                evaluations[_name] += 1
                return _f(*args, **kwargs)
            monkeypatch.setattr(mod, name, counting)
    toarray = sps.csr_matrix.toarray

    def bounded_toarray(self, *args, **kwargs):
        assert self.shape[0] * self.shape[1] <= DENSE_LIMIT, f"a dense {self.shape} matrix"
        return toarray(self, *args, **kwargs)

    monkeypatch.setattr(sps.csr_matrix, "toarray", bounded_toarray)
    init = consistent_initial_conditions(mod, p, 0.0, {int(j): 0.0 for j in dif}, set(dif.tolist()))
    assert init.iterations <= 25   # the Gauss–Newton steps, not the dense least-squares fallback
    assert sum(evaluations.values()) <= 100, evaluations   # measured: 7 residuals, 21 Jacobians
    res = np.zeros(n)
    mod.residual(0.0, init.y0, init.yp0, p, res)
    assert np.abs(res).max() < 1e-8


def _collections_during(action) -> int:
    """How many passes Python's cyclic garbage collector starts while `action` runs."""
    import gc

    started = []

    def count(phase, info):
        if phase == "start":
            started.append(info["generation"])

    gc.callbacks.append(count)
    try:
        action()
    finally:
        gc.callbacks.remove(count)
    return len(started)


def test_compile_pauses_the_garbage_collector_and_restores_it(tmp_path):
    """A compilation makes its long-lived objects (one or more per unknown) without the
    cyclic collector walking them again and again (phc.pipeline.collector_paused: 48.8 → 34.4
    CPU seconds for a 10⁵-element string, docs/reference/limits.md); the collector is
    left as it was found, also after a model error. The 300-element string allocates far
    more than the youngest generation's threshold (700 objects), so a running collector
    would start passes during its compile; this counts them rather than timing anything."""
    import gc

    text = (MODELS / "vibrating_string.yaml").read_text().replace("elements: 16", "elements: 300")
    path = tmp_path / "string300.yaml"
    path.write_text(text)
    bad = tmp_path / "bad.yaml"
    bad.write_text(text.replace("type: string", "type: no_such_component"))
    compile_model = phc.compile_model   # imported before counting (imports make objects too)
    assert gc.isenabled()
    # at most the one pass that may start when the collector is enabled again at the end
    # (with the collector running throughout: about 200 passes)
    assert _collections_during(lambda: compile_model(path, certify=False, backend="numpy")) <= 1
    assert gc.isenabled()
    assert _collections_during(lambda: gc.collect(0)) == 1   # the counter counts a pass
    with pytest.raises(phc.ModelError):
        compile_model(bad, certify=False, backend="numpy")
    assert gc.isenabled()
    gc.disable()
    try:
        compile_model(path, certify=False, backend="numpy")
        assert not gc.isenabled()   # a collector the caller paused stays paused
    finally:
        gc.enable()


def test_incidence_of_a_mesh_reads_every_stored_entry_once(tmp_path):
    """phc.analysis.matching.incidence reads the linear blocks with numpy; the pairs are
    those of reading each equation's symbols and each stored matrix entry one by one
    (written out here), sorted by row then column, without repeats."""
    from phc.analysis.matching import incidence
    from phc.pipeline import build_dae

    text = (MODELS / "euler_bernoulli_beam.yaml").read_text().replace("elements: 6", "elements: 40")
    path = tmp_path / "beam40.yaml"
    path.write_text(text)
    dae, _ = build_dae(path)
    col = {v.symbol: j for j, v in enumerate(dae.variables)}
    col.update({v.dsymbol: j for j, v in enumerate(dae.variables) if v.dsymbol is not None})
    expected = {(i, col[s]) for i, eq in enumerate(dae.equations) for s in eq.expr.free_symbols if s in col}
    for block in dae.linear_blocks:
        for term in block.terms:
            m = term.matrix.tocoo()
            expected |= {(block.rows[int(i)], col[term.symbols[int(j)]]) for i, j in zip(m.row, m.col)}
    assert dae.linear_blocks and len(expected) > 4 * 40   # the mesh's rows are sparse blocks
    rows, cols = incidence(dae)
    assert list(zip(rows.tolist(), cols.tolist())) == sorted(expected)


def test_compiles_in_two_threads_leave_the_collector_as_they_found_it():
    """The collector is one switch for the process: two overlapping pauses (two threads
    compiling at once, the first ending before the second) must leave it running, as it was,
    and keep it paused until the last one ends. With a pause that restored what it saw at its
    own start, the second thread would see it paused, and leave it off for good."""
    import gc
    import threading

    from phc.pipeline import collector_paused

    assert gc.isenabled()
    entered, release_first, release_second = threading.Event(), threading.Event(), threading.Event()
    seen = {}

    def first():
        with collector_paused():
            entered.set()
            release_first.wait(10)

    def second():
        entered.wait(10)
        with collector_paused():
            release_first.set()
            t1.join(10)
            seen["after the first ended"] = gc.isenabled()
            release_second.wait(10)

    t1, t2 = threading.Thread(target=first), threading.Thread(target=second)
    t1.start()
    t2.start()
    t1.join(10)
    release_second.set()
    t2.join(10)
    assert seen == {"after the first ended": False}   # still paused for the second compile
    assert gc.isenabled()                              # running again once both ended


def test_collector_pause_ends_frozen_only_in_the_command(monkeypatch):
    """In the `phc` command (phc._entry.COMMAND), which frees its model only at exit, a pause
    ends by freezing what the block left (the next young collection would walk all of it);
    in a user's process (`import phc`) nothing is frozen, so the collector still frees it."""
    import gc

    import phc._entry as entry
    from phc.pipeline import collector_paused

    assert gc.isenabled()
    monkeypatch.setattr(entry, "COMMAND", False)
    frozen = gc.get_freeze_count()
    with collector_paused():
        kept = [[i] for i in range(1000)]  # containers the collector tracks
        assert not gc.isenabled()
    assert gc.isenabled() and gc.get_freeze_count() == frozen
    monkeypatch.setattr(entry, "COMMAND", True)
    try:
        with collector_paused():
            kept += [[i] for i in range(1000)]
        assert gc.isenabled() and gc.get_freeze_count() >= frozen + 2000
    finally:
        gc.unfreeze()  # the test process goes on collecting as before
    assert gc.get_freeze_count() == 0 and len(kept) == 2000
