"""The restricted Python → C translator (:mod:`phc.codegen.c_translate`) that gives the C step
loop the step logic of :mod:`phc.simulation.step_logic`.

The translation must do what the Python does, bit for bit: the translated driver functions are
compiled and called through ctypes on random inputs and compared with the same Python functions
on NumPy arrays with ``np.array_equal`` (no tolerance: both take the same IEEE operations in the
same order; the C is compiled without fused multiply-adds). Python outside the subset is refused
with the file, line and function named.
"""

from __future__ import annotations

import ctypes
import importlib.util
import textwrap

import numpy as np
import pytest

from phc.codegen import c_backend, c_steps
from phc.codegen.c_translate import PRELUDE, TranslationError, Translator
from phc.simulation import step_logic as sl

DRIVER = ("substeps", "next_step", "predictor_nodes", "lagrange_weights", "polynomial", "extrapolate", "predict",
          "accept")

_WRAPPERS = """
int64_t t_substeps(double interval, double step) { return substeps(interval, step); }
void t_next_step(const double *t_out, double *fst, int64_t *ist) { next_step(t_out, fst, ist); }
void t_predict(int64_t n, const double *y, const double *mid, const double *mid_slope, const double *pt,
               const double *pm, int64_t npred, const int64_t *ist, const double *c, double t, double h,
               double h_prev, const int8_t *algmask, double *guess)
{ predict(n, y, mid, mid_slope, pt, pm, npred, ist, c, t, h, h_prev, algmask, guess); }
int t_accept(int64_t n, double t, double h, double *y, const double *y_new, const double *y_end, double *y_prev,
             double *mid, double *mid_slope, double *pt, double *pm, int64_t npred, double *ys, int64_t nout,
             double *yps, double *fst, int64_t *ist)
{ return accept(n, t, h, y, y_new, y_end, y_prev, mid, mid_slope, pt, pm, npred, ys, nout, yps, nout, fst, ist); }
"""


@pytest.fixture(scope="module")
def driver():
    text = ("#include <math.h>\n#include <stdint.h>\n" + PRELUDE
            + Translator(sl, sl.C_SIGNATURES, {}).translate(DRIVER) + _WRAPPERS)
    lib, why = c_backend.runtime_library(text, c_steps.FLAGS)
    if lib is None:
        pytest.skip(f"no C compiler: {why}")
    return lib


def _p(a):
    return a.ctypes.data_as(ctypes.c_void_p)


def test_step_logic_translates_and_steps_c_is_complete():
    """Every function the C loop takes from step_logic translates, and steps.c has the place for
    them once."""
    text = c_steps.translation()
    for name in c_steps.TRANSLATED:
        assert f"step_logic.{name} (translated" in text
    assert c_steps.SOURCE.read_text(encoding="utf-8").count(c_steps.MARKER) == 1
    # the chunk loop as well: steps.c does not define the library's entry by hand, the translation does
    assert "void phc_steps_chunk(" not in c_steps.SOURCE.read_text(encoding="utf-8")
    assert text.count("void phc_steps_chunk(") == 1 and "static void chunk(" in text


def test_substeps_and_next_step_match_python_bit_for_bit(driver):
    rng = np.random.default_rng(1)
    driver.t_substeps.restype = ctypes.c_int64
    driver.t_substeps.argtypes = [ctypes.c_double, ctypes.c_double]
    for interval, step in [(1.0, 0.1), (0.3, 0.1), (1.0, 0.0), (2.5e-3, 1e-3)] + [
            tuple(rng.uniform(1e-3, 1.0, 2)) for _ in range(200)]:
        assert driver.t_substeps(interval, step) == sl.substeps(interval, step)
    t_out = np.cumsum(rng.uniform(0.01, 0.2, 12))
    for k in range(1, 12):
        fst = rng.uniform(size=sl._NF)
        fst[sl._STEP] = rng.uniform(1e-3, 0.05)
        ist = np.zeros(sl._NI, dtype=np.int64)
        ist[sl._K] = k
        fst_c, ist_c = fst.copy(), ist.copy()
        sl.next_step(t_out, fst, ist)
        driver.t_next_step(_p(t_out), _p(fst_c), _p(ist_c))
        assert np.array_equal(fst, fst_c) and np.array_equal(ist, ist_c)


@pytest.mark.parametrize("order, order_alg, nmid", [(0, 0, 0), (1, 0, 5), (2, 1, 2), (3, 1, 4), (5, 2, 6),
                                                    (7, 3, 8)])
def test_predict_matches_python_bit_for_bit(driver, order, order_alg, nmid):
    rng = np.random.default_rng(order * 10 + nmid)
    n, npred = 9, 8
    y, mid, slope = rng.normal(size=(3, n))
    pt = np.sort(rng.uniform(0.0, 1.0, npred))[::-1].copy()
    pm = rng.normal(size=(npred, n))
    algmask = rng.integers(0, 3, n).astype(np.int8)
    c = np.zeros(sl._NC)
    c[sl._ORDER], c[sl._ORDER_ALG] = order, order_alg
    ist = np.zeros(sl._NI, dtype=np.int64)
    ist[sl._HAS_MID], ist[sl._NMID] = int(nmid > 0), nmid
    t, h, h_prev = 1.0 + rng.uniform(), rng.uniform(1e-3, 1e-2), rng.uniform(1e-3, 1e-2)
    guess, guess_c = np.empty(n), np.empty(n)
    sl.predict(y, mid, slope, pt, pm, ist, c, t, h, h_prev, algmask, guess)
    driver.t_predict(ctypes.c_int64(n), _p(y), _p(mid), _p(slope), _p(pt), _p(pm), ctypes.c_int64(npred), _p(ist),
                     _p(c), ctypes.c_double(t), ctypes.c_double(h), ctypes.c_double(h_prev), _p(algmask),
                     _p(guess_c))
    assert np.array_equal(guess, guess_c)


@pytest.mark.parametrize("has_mid, j, max_steps", [(0, 0, 100), (1, 2, 100), (1, 0, 5), (1, 3, 100)])
def test_accept_matches_python_bit_for_bit(driver, has_mid, j, max_steps):
    rng = np.random.default_rng(j + 7 * has_mid)
    n, npred, nout = 6, 4, 5
    arrays = [rng.normal(size=n) for _ in range(6)]  # y, y_new, y_end, y_prev, mid, mid_slope
    pt, pm = rng.uniform(size=npred), rng.normal(size=(npred, n))
    ys, yps = rng.normal(size=(nout, n)), rng.normal(size=(nout, n))
    fst = rng.uniform(size=sl._NF)
    ist = np.zeros(sl._NI, dtype=np.int64)
    ist[sl._HAS_MID], ist[sl._J], ist[sl._SUBSTEPS], ist[sl._K] = has_mid, j, 4, 2
    ist[sl._STEPS], ist[sl._MAX_STEPS], ist[sl._NMID] = 4, max_steps, 3
    t, h = 0.5, 1e-2
    py = [a.copy() for a in arrays + [pt, pm, ys, yps, fst, ist]]
    cc = [a.copy() for a in arrays + [pt, pm, ys, yps, fst, ist]]
    done = sl.accept(t, h, *py[:6], *py[6:])
    y, y_new, y_end, y_prev, mid, slope, pt_c, pm_c, ys_c, yps_c, fst_c, ist_c = cc
    done_c = driver.t_accept(ctypes.c_int64(n), ctypes.c_double(t), ctypes.c_double(h), _p(y), _p(y_new), _p(y_end),
                             _p(y_prev), _p(mid), _p(slope), _p(pt_c), _p(pm_c), ctypes.c_int64(npred), _p(ys_c),
                             ctypes.c_int64(nout), _p(yps_c), _p(fst_c), _p(ist_c))
    assert bool(done_c) == done
    for a, b in zip(py, cc):
        assert np.array_equal(a, b)


# The chunk loop (step_logic.chunk) with stand-ins for the loop's three operations it calls, the same
# in C and in Python: a "step" out = guess + h y that fails from t_fail on and is ill-conditioned
# from t_ill on, a routine look that passes before t_look, and a switching function that crosses
# zero at the end of a step past t_event.
_CHUNK_OPS = """
struct phc_steps { double t_fail, t_ill, t_look, t_event; };
static int64_t op_advance(int64_t n, const struct phc_steps *w, double t, double h, const double *y,
                          const double *guess, double *out, int *ill)
{
    for (int64_t i = 0; i < n; ++i)
        out[i] = guess[i] + h * y[i];
    *ill = t >= w->t_ill;
    return t >= w->t_fail ? 1 : 0;
}
static int op_far_from_singular(int64_t n, const struct phc_steps *w, double t, const double *y, const double *yp,
                                double hm)
{
    (void)n; (void)y; (void)yp; (void)hm;
    return t < w->t_look;
}
static int op_watch(int64_t n, const struct phc_steps *w, double t, double h, const double *y, const double *y_new)
{
    (void)n; (void)y; (void)y_new;
    return t + h > w->t_event;
}
"""

_CHUNK_WRAPPER = """
void t_chunk(int64_t n, const struct phc_steps *w, const double *t_out, double *ys, double *yps, int64_t nout, double *y,
             double *mid, double *mid_slope, double *y_prev, double *y_new, double *pt, double *pm, int64_t npred,
             double *fst, int64_t *ist, const double *c, const int8_t *algmask, double *guess, double *yp,
             int64_t budget)
{ chunk(n, w, t_out, ys, nout, yps, nout, y, mid, mid_slope, y_prev, y_new, pt, pm, npred, fst, ist, c, algmask, guess,
        yp, budget); }
"""


def _chunk_in_python():
    """step_logic.chunk's code with the stand-in operations of _CHUNK_OPS as its globals."""
    import types

    def _advance(ws, t, h, y, guess, out):
        sl._copy(guess + h * y, out)
        return (sl._FAIL if t >= ws[0] else sl._OK), t >= ws[1]

    def _far_from_singular(ws, t, y, yp, hm):
        return t < ws[2]

    def _watch(ws, t, h, y, y_new):
        return t + h > ws[3]

    namespace = {**vars(sl), "_advance": _advance, "_far_from_singular": _far_from_singular, "_watch": _watch}
    return types.FunctionType(sl.chunk.__code__, namespace, "chunk")


@pytest.fixture(scope="module")
def chunk_c():
    ops = {k: v for k, v in c_steps._operations().items() if k in ("_advance", "_far_from_singular", "_watch")}
    text = ("#include <math.h>\n#include <stdint.h>\n" + PRELUDE + _CHUNK_OPS
            + Translator(sl, sl.C_SIGNATURES, ops).translate(DRIVER + ("looks", "chunk")) + _CHUNK_WRAPPER)
    lib, why = c_backend.runtime_library(text, c_steps.FLAGS)
    if lib is None:
        pytest.skip(f"no C compiler: {why}")
    return lib


@pytest.mark.parametrize("t_fail, t_ill, t_look, t_event, budget, max_steps, status", [
    (np.inf, np.inf, np.inf, np.inf, 10**6, 10**6, sl._DONE),  # the whole grid, its looks passing
    (np.inf, np.inf, np.inf, np.inf, 7, 10**6, sl._BUDGET),
    (0.33, np.inf, np.inf, np.inf, 10**6, 10**6, sl._HARD),  # a step that fails
    (np.inf, 0.2, np.inf, np.inf, 10**6, 10**6, sl._HARD),  # ill-conditioned, LOOK_GAP steps after the last look
    (np.inf, np.inf, 0.27, np.inf, 10**6, 10**6, sl._LOOK),  # a routine look that does not pass
    (np.inf, np.inf, np.inf, np.inf, 10**6, 13, sl._MAXSTEPS),
    (np.inf, np.inf, np.inf, 0.41, 10**6, 10**6, sl._EVENT),  # a switching function crossed: handed back
])
def test_the_chunk_loop_matches_python_bit_for_bit(chunk_c, t_fail, t_ill, t_look, t_event, budget, max_steps,
                                                   status):
    """step_logic.chunk, the compiled loops' chunk (the C loop's phc_steps_chunk is its translation),
    stops with the same status after the same steps and leaves every state array as Python does."""
    rng = np.random.default_rng(int(status) + budget % 5)
    n, npred, nout = 5, 4, 6
    t_out = np.linspace(0.0, 1.0, nout)
    ys, yps = np.zeros((nout, n)), np.zeros((nout, n))
    y, mid, slope, y_prev, y_new, guess, yp = (rng.normal(size=n) for _ in range(7))
    pt, pm = np.zeros(npred), np.zeros((npred, n))
    fst = np.zeros(sl._NF)
    fst[sl._STEP] = 0.03
    ist = np.zeros(sl._NI, dtype=np.int64)
    ist[sl._K], ist[sl._LAST_LOOK], ist[sl._MAX_STEPS], ist[sl._MONITOR] = 1, -100, max_steps, 1
    c = np.zeros(sl._NC)
    c[sl._ORDER], c[sl._ORDER_ALG], c[sl._EVERY] = 2, 1, 20  # 35 steps: looks at steps 0 and 20
    algmask = rng.integers(0, 3, n).astype(np.int8)
    arrays = [ys, yps, y, mid, slope, y_prev, y_new, pt, pm, fst, ist, guess, yp]
    py = [a.copy() for a in arrays]
    cc = [a.copy() for a in arrays]
    _chunk_in_python()((t_fail, t_ill, t_look, t_event), t_out, *py[:11], c, algmask, *py[11:], budget)
    ws = (ctypes.c_double * 4)(t_fail, t_ill, t_look, t_event)
    ys_c, yps_c, y_c, mid_c, slope_c, y_prev_c, y_new_c, pt_c, pm_c, fst_c, ist_c, guess_c, yp_c = cc
    chunk_c.t_chunk(ctypes.c_int64(n), ws, _p(t_out), _p(ys_c), _p(yps_c), ctypes.c_int64(nout), _p(y_c), _p(mid_c),
                    _p(slope_c), _p(y_prev_c), _p(y_new_c), _p(pt_c), _p(pm_c), ctypes.c_int64(npred), _p(fst_c),
                    _p(ist_c), _p(c), _p(algmask), _p(guess_c), _p(yp_c), ctypes.c_int64(budget))
    assert py[10][sl._STATUS] == status  # the case reaches the status it is written for
    assert py[10][sl._STEPS] >= 5  # and takes steps (a look and the predictor's history on the way)
    for a, b in zip(py, cc):
        assert np.array_equal(a, b)


def _module(tmp_path, source):
    path = tmp_path / "logic.py"
    path.write_text("import numpy as np\n\n" + textwrap.dedent(source), encoding="utf-8")
    spec = importlib.util.spec_from_file_location("logic_under_test", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_subset_is_translated(tmp_path):
    """Locals typed from their values (int64 where only integers are assigned, double where any
    double is), Python's true division of integers, min/max, vector statements."""
    m = _module(tmp_path, """
        _K = 3

        def f(a, k, x, out):
            j = k + _K
            r = j / 2
            s = 0
            for i in range(k):
                s = s + x[i]
            _copy(a * x + min(r, 1.0), out)
            return s, j
        """)
    text = Translator(m, {"f": (("f", "i", "v", "v"), ("f", "i"))}, {}).translate(["f"])
    assert "static double f(int64_t n, double a, int64_t k, const double *x, double *out, int64_t *result1)" in text
    assert "int64_t j = 0;" in text and "double r = 0;" in text and "double s = 0;" in text
    assert "r = ((double)(j) / 2);" in text and "j = (k + 3 /* _K */);" in text
    assert "out[i2] = ((a * x[i2]) + py_min_f(r, 1.0));" in text
    assert "*result1 = j;" in text and "return s;" in text


@pytest.mark.parametrize("body, what", [
    ("while k > 0:\n        k -= 1\n    return k", "the statement While"),
    ("return 0 < k < 3", "a chained comparison"),
    ("d = {}\n    return k", "the expression Dict"),
    ("return k % 2.0", "the operator Mod of doubles"),
    ("return x", "the vector 'x' where a scalar is expected"),
    ("return np.sum(x)", "the call 'np.sum'"),
])
def test_python_outside_the_subset_is_refused_with_its_line(tmp_path, body, what):
    m = _module(tmp_path, f"""
def g(k, x):
    {body}
""")
    with pytest.raises(TranslationError) as err:
        Translator(m, {"g": (("i", "v"), ("i",))}, {}).translate(["g"])
    message = str(err.value)
    assert message.startswith(f"{tmp_path / 'logic.py'}:") and "in g:" in message and what in message, message
    line = int(message.split(":")[1])
    assert 5 <= line <= 7  # the function starts on line 5 of the file: its body's line is named


def test_integer_remainder_and_while_true_are_pythons(tmp_path):
    """``%`` of integers takes the divisor's sign as Python's does (C's takes the dividend's), and
    ``while True:`` is left by return as in Python."""
    m = _module(tmp_path, """
        def r(a, b):
            k = 0
            while True:
                if k >= 3:
                    return a % b + k
                k += 1
        """)
    text = "#include <math.h>\n#include <stdint.h>\n" + PRELUDE + Translator(m, {"r": (("i", "i"), ("i",))}, {}).translate(
        ["r"]) + "int64_t t_r(int64_t a, int64_t b) { return r(a, b); }\n"
    lib, why = c_backend.runtime_library(text, c_steps.FLAGS)
    if lib is None:
        pytest.skip(f"no C compiler: {why}")
    lib.t_r.restype, lib.t_r.argtypes = ctypes.c_int64, [ctypes.c_int64, ctypes.c_int64]
    for a in range(-7, 8):
        for b in (-3, -1, 1, 2, 5):
            assert lib.t_r(a, b) == m.r(a, b), (a, b)


def test_a_function_without_a_signature_is_refused(tmp_path):
    m = _module(tmp_path, "def h(a):\n    return a\n")
    with pytest.raises(TranslationError, match="in h: no C signature"):
        Translator(m, {}, {}).translate(["h"])


def test_a_local_vector_named_twice_is_a_copy_only_where_neither_is_written_in_place(tmp_path):
    """``b = a`` of two local vectors is Python's one array under two names; a C copy is the same
    only while neither is changed in place: the translator copies then, else refuses."""
    m = _module(tmp_path, """
        def read_only(x, out):
            a = x.copy()
            b = a
            b = 2.0 * x
            _copy(a + b, out)

        def written(x, out):
            a = x.copy()
            b = a
            _add(b, x)
            _copy(a, out)
        """)
    text = Translator(m, {"read_only": (("v", "v"), ())}, {}).translate(["read_only"])
    assert "b[i2] = a[i2];" in text and "double b[n];" in text
    with pytest.raises(TranslationError, match=r"logic.py:12: in written: b = a: a vector named twice"):
        Translator(m, {"written": (("v", "v"), ())}, {}).translate(["written"])


def test_the_look_logic_of_the_native_ida_driver_is_pythons():
    """The native IDA driver's routine look decides with phc.simulation.look_cadence's functions,
    translated (float constants of the module, math.log10, NaN for "no look"): on a grid of cadences
    and ratios (NaN, far below, near and far above FAR_RATIO, flat and moving) and of look times and
    step counts, the C gives Python's answers exactly."""
    import itertools
    import math

    from phc.simulation import look_cadence as lc

    text = ("#include <math.h>\n#include <stdint.h>\n" + PRELUDE
            + Translator(lc, lc.C_SIGNATURES, {}).translate(("cadence_after", "brackets_minimum", "crawls"))
            + "int64_t t_cadence(int64_t c, int64_t b, double x, double r) { return cadence_after(c, b, x, r); }\n"
            "int t_brackets(double a, double b, double c, double d, double e, double f)"
            " { return brackets_minimum(a, b, c, d, e, f); }\n"
            "int t_crawls(double h, double t, double te, int64_t s, int64_t m, int64_t k)"
            " { return crawls(h, t, te, s, m, k); }\n")
    lib, why = c_backend.runtime_library(text, c_steps.FLAGS)
    if lib is None:
        pytest.skip(f"no C compiler: {why}")
    D, I = ctypes.c_double, ctypes.c_int64
    lib.t_cadence.argtypes, lib.t_cadence.restype = [I, I, D, D], I
    lib.t_brackets.argtypes, lib.t_brackets.restype = [D] * 6, ctypes.c_int
    lib.t_crawls.argtypes, lib.t_crawls.restype = [D, D, D, I, I, I], ctypes.c_int
    ratios = [math.nan, 1e-12, 1e-6, 1.0000001e-6, 2e-6, 0.01, 0.0125, 0.0126, 0.02, 0.5]
    for cadence, base in ((10, 10), (15, 10), (300, 10), (320, 10), (20, 20)):
        for before, ratio in itertools.product(ratios, ratios):
            assert lib.t_cadence(cadence, base, before, ratio) == lc.cadence_after(cadence, base, before, ratio)
    assert lc.next_cadence(10, 10, None, 0.5) == lc.cadence_after(10, 10, math.nan, 0.5) == 10
    times = [math.nan, 0.0, 1.0, 2.0]
    for t0, t1, t2 in itertools.product(times, repeat=3):
        for r0, r1, r2 in itertools.product([math.nan, 0.1, 0.2], repeat=3):
            assert bool(lib.t_brackets(t0, r0, t1, r1, t2, r2)) == lc.brackets_minimum(t0, r0, t1, r1, t2, r2)
    for h, steps, check in itertools.product([1e-9, 1e-3, 0.5], [0, 10, 99, 100], [0, 50]):
        assert bool(lib.t_crawls(h, 0.25, 1.0, steps, 100, check)) == lc.crawls(h, 0.25, 1.0, steps, 100, check)


_SEARCH_WRAPPERS = """
struct phc_steps { double centre, floor, stop; };
static double op_ratio_at_time(const struct phc_steps *ws, double t, int *below, int *unknown)
{
    const double r = (t - ws->centre) * (t - ws->centre) + ws->floor;
    *below = r < 1e-8;
    *unknown = t > ws->stop;
    return r;
}
"""


def test_the_search_between_looks_and_its_interpolant_are_pythons():
    """The monitor's search for a minimum between its looks (look_cadence.golden_search) and the Hermite
    interpolant it looks along, translated for the native IDA driver: on parabolas (t − centre)² + floor,
    "below" under 1e-8 (so found where floor is 1e-9, never where it is 1e-3), with and without `minimum`,
    with and without the end ratios, and an operation that cannot tell beyond `stop`, the C search gives
    Python's result bit for bit (every outcome occurs), and the interpolant Python's states."""
    import math

    from phc.codegen.c_translate import Op
    from phc.simulation import look_cadence as lc

    ops = {"_ratio_at_time": Op("op_ratio_at_time", ("ws", "f"), ("f", "b", "b"))}
    text = ("#include <math.h>\n#include <stdint.h>\n" + PRELUDE + _SEARCH_WRAPPERS
            + Translator(lc, lc.C_SIGNATURES, ops).translate(("hermite", "golden_search"))
            + "int64_t t_search(double centre, double floor, double stop, double a, double b, double threshold,"
            " int64_t iterations, double fa, double fb, int minimum, double *t, double *r)\n"
            "{ struct phc_steps ws = {centre, floor, stop};"
            " return golden_search(&ws, a, b, threshold, iterations, fa, fb, minimum, t, r); }\n"
            "void t_hermite(int64_t n, double ta, const double *ya, const double *ypa, double tb, const double *yb,"
            " const double *ypb, double t, double *y, double *yp) { hermite(n, ta, ya, ypa, tb, yb, ypb, t, y, yp); }\n")
    lib, why = c_backend.runtime_library(text, c_steps.FLAGS)
    if lib is None:
        pytest.skip(f"no C compiler: {why}")
    D, I, P = ctypes.c_double, ctypes.c_int64, ctypes.c_void_p
    lib.t_search.argtypes, lib.t_search.restype = [D] * 6 + [I, D, D, ctypes.c_int, P, P], I
    lib.t_hermite.argtypes, lib.t_hermite.restype = [I, D, P, P, D, P, P, D, P, P], None
    t_c, r_c = np.zeros(1), np.zeros(1)
    cases, codes = 0, set()
    for centre in (0.1, 0.37, 0.9):
        for floor in (1e-3, 1e-9):
            for stop in (math.inf, 0.5):
                for threshold in (1e-6, 1e-2):
                    for minimum in (False, True):
                        for fa, fb in ((math.nan, math.nan), (0.2, 0.3)):
                            def op(ws, t, centre=centre, floor=floor, stop=stop):
                                r = (t - centre) * (t - centre) + floor
                                return r, r < 1e-8, t > stop

                            expected = lc.run_golden_search(op, 0.0, 1.0, threshold, 80, fa, fb, minimum)
                            code = lib.t_search(centre, floor, stop, 0.0, 1.0, threshold, 80, fa, fb, minimum, _p(t_c),
                                                _p(r_c))
                            assert (code, t_c[0], r_c[0]) == expected
                            codes.add(code)
                            cases += 1
    assert cases == 96 and codes == {-1, 0, 1}  # every outcome met
    rng = np.random.default_rng(3)
    n = 7
    ya, ypa, yb, ypb = (rng.standard_normal(n) for _ in range(4))
    for t in (0.2, 0.25, 0.31, 0.6):
        y, yp = np.zeros(n), np.zeros(n)
        lc.hermite(0.2, ya, ypa, 0.6, yb, ypb, t, y, yp)
        yc, ypc = np.zeros(n), np.zeros(n)
        lib.t_hermite(n, 0.2, _p(ya), _p(ypa), 0.6, _p(yb), _p(ypb), t, _p(yc), _p(ypc))
        assert np.array_equal(y, yc) and np.array_equal(yp, ypc)
