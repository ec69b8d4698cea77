/* The fixed-step methods' step loops in C, for phc's C back end: the implicit midpoint rule,
 * the discrete-gradient step and the fourth-order composition (midpoint4).
 *
 * Part of phc (a compiler for port-Hamiltonian models); compiled once per machine and phc
 * version into its own shared library (phc/codegen/c_steps.py) and kept in phc's signed
 * cache beside the models' libraries. It does not depend on the model: the model's compiled
 * residual, Jacobian, position invariants, Hamiltonian, energy scale and port powers (the
 * functions of the library phc prints for the model, phc/codegen/c_printer.py) are handed to it
 * as function pointers and called directly.
 *
 * One call, phc_steps_chunk(run, budget) (generated: see below), takes up to `budget` steps of the method
 * ist[I_METHOD] on the output grid of phc.simulation.midpoint.integrate_fixed_step, and returns.
 * Every method's stages are solved by one Newton iteration (`newton`, translated): the implicit
 * midpoint rule is one stage
 *
 *     F(t + h/2, (y + y1)/2, (y1 - y)/h) = 0,  the position-constraint rows g(t + h, y1) = 0
 *
 * (the GGL formulation of T. Berger, R. Hochdahl, T. Reis, R. Seifried, "Port-Hamiltonian
 * modelling of coupled rigid/flexible multibody systems", the rigid multibody DAE, eq. (3):
 * velocity constraints at the midpoint, position constraints at the step end); the discrete
 * gradient (phc.simulation.discrete_gradient) solves the same stage at the point y + s (y1 - y)
 * and a secant iteration on s makes the discrete energy balance of the paper's Remark 3 "Energy
 * balance" hold for a non-quadratic H; midpoint4 (phc.simulation.midpoint4) is three midpoint
 * stages of sizes g1 h, g2 h, g1 h (the triple jump) with its own predictor and passivity guard.
 * Between chunks the Python driver (phc.simulation.compiled_steps.integrate, shared with the
 * numba loop) reports progress and sees Ctrl-C. A step that is not routine is handed back to it,
 * which then does exactly what the Python loop does: a step that fails or cannot evaluate the
 * model (status HARD: the retry from the constant predictor, the split, the discrete gradient's
 * midpoint fallback, midpoint4's passivity message, the message naming the row), a step Newton
 * found ill-conditioned (HARD), a routine look of the singularity monitor that is not clearly
 * far from singular (LOOK: Python's monitor looks with its SVD and decides).
 *
 * What each step does is written once, in Python, in phc/simulation/step_logic.py, which the Python
 * loop runs and the numba kernel compiles. Its Newton iteration (`newton`: the stopping rules, the
 * refresh of the Newton matrix, the round-off acceptance), the methods' steps (`discrete_gradient`,
 * `midpoint4`), the driver's bookkeeping (`next_step`, `predict`, `looks`, `accept`) and the chunk
 * loop itself (`chunk`, which the numba kernel runs too) are not written in this file:
 * phc.codegen.c_steps.source() translates them to C (phc/codegen/c_translate.py) and puts them,
 * with the library's entry phc_steps_chunk (chunk on this file's struct, written from chunk's
 * parameters), at the line PHC_STEP_LOGIC below, beside the operations they call (op_begin,
 * op_refactor, op_correct, op_precision, op_consistent, op_stage, op_advance,
 * op_far_from_singular, the monitor's routine look, and op_watch, the switching functions of a run
 * with events). The state arrays have the layout of the
 * numba loop's (checked when the library is loaded: phc_steps_layout). Not here: the
 * mixed-precision corrections of the numba loop (every correction here is in double precision, so
 * step_logic's precision events never occur).
 *
 * Linear algebra: the Newton matrix s*(F_y + cj*F_yp) (the end-constraint rows from g_y) is
 * equilibrated by powers of two as the Python loop's sparse LU is (phc.simulation.midpoint.
 * equilibration: columns by the nominal scales, else to a largest entry in [1, 2), then rows),
 * factorized by a dense LU with partial pivoting (dense_lu.c, put at the line PHC_DENSE_LU below
 * when the library is built; the native IDA driver's routine look uses it too), and each correction is two
 * triangular solves. Not LAPACK: a portable link to it needs a LAPACK library on the machine
 * or SciPy's private one, and at the sizes this loop serves (at most 400 unknowns, a few
 * factorizations per hundred steps) the plain loops cost little; they are column oriented, so
 * that the compiler vectorizes their inner loops without reordering any sum. The solves are
 * most of a routine step's time (one per Newton iteration): they take four columns a pass
 * and, like the LU and the stage point's loops, run in an AVX2 copy where the CPU has AVX2 — every entry takes the
 * same IEEE operations in the same order on every path, so the results do not depend on the
 * CPU (no -ffast-math, no fused multiply-adds).
 *
 * Re-entrant: no static mutable state. Every array is the caller's (struct phc_steps).
 */

#include <math.h>
#include <stdint.h>
#include <string.h>

#define PHC_STEPS_ABI 5

typedef void (*phc_residual_fn)(double t, const double *y, const double *yp, const double *p, double *out);
typedef void (*phc_jacobian_fn)(double t, const double *y, const double *yp, const double *p, double cj,
                                double *out);
typedef void (*phc_invariants_fn)(double t, const double *y, const double *p, double *out);
typedef double (*phc_scalar_fn)(double t, const double *y, const double *p);
typedef void (*phc_powers_fn)(double t, const double *y, const double *yp, const double *p, double *out);

/* outcome of a stage solve or a step (phc.simulation.step_logic: _OK, _FAIL, _SINGULAR, _EVAL, _PASSIVITY) */
enum { OK = 0, FAIL = 1, SINGULAR = 2, EVAL = 3, PASSIVITY = 4 };

/* the constants vector c (phc.simulation.step_logic: _TOL ... _RUN_ENERGY; C_RUN_ENERGY since ABI 5) */
enum { C_TOL, C_RATE, C_FLOOR, C_MAX_AGE, C_MAX_NEWTON, C_BAL_TOL, C_MAX_SECANT, C_S_MIN, C_S_MAX, C_THRESHOLD,
       C_EVERY, C_G1, C_G2, C_M0, C_M1, C_M2, C_ORDER, C_ZONE, C_STAGNATION, C_ONE, C_ZERO, C_ORDER_ALG,
       C_STRIKES, C_RUN_ENERGY, C_NC };

/* status of a chunk (phc.codegen.numba_steps_kernel: _BUDGET ... _MAXSTEPS, _EVENT) */
enum { ST_BUDGET, ST_DONE, ST_HARD, ST_LOOK, ST_MAXSTEPS, ST_EVENT };

/* the integer state ist[] (numba_steps_kernel: _K ... _STRIKES), then the ages of the matrices */
enum { I_K, I_J, I_SUBSTEPS, I_STEPS, I_LAST_LOOK, I_HAS_MID, I_MAX_STEPS, I_STATUS, I_NFEV, I_NFACT, I_HIST,
       I_MONITOR, I_METHOD, I_CODE, I_ILL, I_E, I_NEND, I_NMID, I_LOWP, I_STRIKES, I_NI };
#define I_AGE0 I_NI

/* the float state fst[] (numba_steps_kernel: _T, _H, _H_PREV, _STEP) */
enum { F_T, F_H, F_H_PREV, F_STEP, F_NF };

/* Most midpoints the predictor keeps (phc.simulation.midpoint.MAX_PREDICTOR_ORDER + 1, checked by the caller). */
#define MAX_NODES 16

/* Everything one run uses: the model and the grid (read only), the run's state (kept between
 * chunks: the driver reads and writes it too), scratch. The Python side (phc/codegen/c_steps.py)
 * allocates every array and mirrors this struct field by field. */
struct phc_steps {
    /* sizes: unknowns, Jacobian entries, position-constraint rows, output times, predictor nodes */
    int64_t n, njac, nend, nout, npred;
    /* the model's compiled functions and parameters */
    phc_residual_fn residual;
    phc_jacobian_fn jacobian;
    phc_invariants_fn invariants;
    const double *p;
    const int64_t *jrows, *jcols;   /* njac: the Jacobian's pattern (JAC_ROWS, JAC_COLS) */
    const int64_t *end_rows;        /* nend: the rows replaced by g(t + h, y1) */
    const int8_t *emask;            /* njac: 1 where the entry is in such a row */
    const int8_t *algmask;          /* n: 0 differential, 1 algebraic, 2 a GGL multiplier */
    const double *weights;          /* n Newton weights, or NULL (relative to |y| + 1) */
    const double *colscale;         /* n nominal scales the monitor scales columns by, or NULL */
    const double *c;                /* the constants vector */
    const double *t_out;            /* nout output times */
    /* the run's state */
    double *ys, *yps;               /* nout x n outputs */
    double *y, *mid, *mid_slope, *y_prev, *y_new;   /* n each */
    double *pt, *pm;                /* npred midpoint times, npred x n midpoints (newest first) */
    double *fst;                    /* F_NF */
    int64_t *ist;                   /* I_NI + 2 */
    /* the Newton matrices (two, as the numba loop keeps: midpoint4's middle stage uses matrix 1, every other stage matrix 0) */
    double *lu;                     /* 2 x n x n: LU of the equilibrated matrix, column-major */
    int64_t *piv;                   /* 2 x n: row interchanges */
    int64_t *perm;                  /* 2 x n: the row interchanges as one permutation (lu_permutation) */
    double *eq;                     /* 2 x 2n: row scales, then column scales */
    double *matf;                   /* 2 x 3: step size, evaluation point, factorized (1) */
    /* scratch */
    double *xs, *d, *r, *guess, *yp, *g;   /* n each (g: nend) */
    double *jbuf, *ebuf;            /* njac each */
    double *mon;                    /* n x n: the monitor's matrix */
    int64_t *monpiv;                /* n */
    double *monv;                   /* 3n */
    /* the discrete gradient and midpoint4 (ABI 3): H, the energy scale, the port powers
     * (supplied, dissipated) of the model */
    phc_scalar_fn hamiltonian, energy_scale;
    phc_powers_fn powers;
    double *hist_t, *hist_v;        /* 2 x 3, 2 x 3 x n: midpoint4's substep midpoints of the last steps (I_HIST) */
    double *sub;                    /* 3 x n: midpoint4's substep midpoints of this step */
    double *start, *y1in;           /* n each: a stage's start and its Newton start */
    double *y_half, *y_best, *y_sec;   /* n each: the discrete gradient's s = 1/2 step, best, last secant iterate */
    /* a run with switching conditions (ABI 4; nwatch = 0: none): the model's switching functions
     * (phc_events of its library, nev values), the watched functions w_i = a_i + b_i v[k_i] as rows
     * a, b, k of wmap (3 x nwatch: phc.simulation.compiled_steps.watch_map), their values at the
     * step's start and end, the model's values, the step's slope (n) */
    phc_residual_fn events;
    int64_t nwatch, nev;
    const double *wmap;
    double *wprev, *wnew, *vbuf, *slope;
};

/* PHC_DENSE_LU */

/* 1/2^e with 2^e <= big < 2^(e+1), 1 where big is not positive: an exact scaling of big to [1, 2)
 * (phc.simulation.midpoint._power_of_two_below) */
static double power_of_two_below(double big)
{
    int e;
    if (!(big > 0.0))
        return 1.0;
    frexp(big, &e);
    return ldexp(1.0, -(e - 1));
}

/* The row interchanges of lu_factor as one permutation: (P x)_i = x[perm[i]], for the caller
 * to gather the right-hand side of lu_solve (without the interchanges one after the other). */
static void lu_permutation(int64_t n, const int64_t *piv, int64_t *perm)
{
    for (int64_t i = 0; i < n; ++i)
        perm[i] = i;
    for (int64_t k = 0; k < n; ++k) {
        const int64_t tmp = perm[k];
        perm[k] = perm[piv[k]];
        perm[piv[k]] = tmp;
    }
}

/* ---- the operations of phc.simulation.step_logic.newton ---------------------------------- */

/* The stage point xs = y + s (y1 - y) and the difference quotient d = (y1 - y)/h of the iterate
 * y1 (a division an unknown: in AVX2's four lanes where the CPU has them, as lu_solve). */
static inline __attribute__((always_inline)) void stage_point_body(int64_t n, const double *restrict y,
                                                                   const double *restrict y1, double s, double h,
                                                                   double *restrict xs, double *restrict d)
{
    for (int64_t i = 0; i < n; ++i) {
        const double dy = y1[i] - y[i];
        xs[i] = y[i] + s * dy;
        d[i] = dy / h;
    }
}

/* The Newton test's weights' quotients q = w/(1 + |y1| w) (correct), likewise. */
static inline __attribute__((always_inline)) void quotients_body(int64_t n, const double *restrict wt,
                                                                 const double *restrict y1, double *restrict q)
{
    for (int64_t i = 0; i < n; ++i)
        q[i] = wt[i] / (1.0 + fabs(y1[i]) * wt[i]);
}

#ifdef PHC_AVX2_DISPATCH
__attribute__((target("avx2"))) static void stage_point_avx2(int64_t n, const double *y, const double *y1, double s,
                                                              double h, double *xs, double *d)
{
    stage_point_body(n, y, y1, s, h, xs, d);
}

__attribute__((target("avx2"))) static void quotients_avx2(int64_t n, const double *wt, const double *y1, double *q)
{
    quotients_body(n, wt, y1, q);
}
#endif

static void stage_point(int64_t n, const double *y, const double *y1, double s, double h, double *xs, double *d)
{
#ifdef PHC_AVX2_DISPATCH
    if (__builtin_cpu_supports("avx2")) {
        stage_point_avx2(n, y, y1, s, h, xs, d);
        return;
    }
#endif
    stage_point_body(n, y, y1, s, h, xs, d);
}

static void quotients(int64_t n, const double *wt, const double *y1, double *q)
{
#ifdef PHC_AVX2_DISPATCH
    if (__builtin_cpu_supports("avx2")) {
        quotients_avx2(n, wt, y1, q);
        return;
    }
#endif
    quotients_body(n, wt, y1, q);
}

/* F at the stage point of the iterate y1, the end-constraint rows replaced by g(t + h, y1), into
 * out; whether every entry is finite (numba_steps_kernel._stage_residual) */
static int stage_residual(const struct phc_steps *w, double t, double h, const double *y, const double *y1, double s,
                          double *out)
{
    const int64_t n = w->n;
    stage_point(n, y, y1, s, h, w->xs, w->d);
    w->residual(t + s * h, w->xs, w->d, w->p, out);
    if (w->nend > 0) {
        w->invariants(t + h, y1, w->p, w->g);
        for (int64_t i = 0; i < w->nend; ++i)
            out[w->end_rows[i]] = w->g[i];
    }
    return all_finite(n, out);
}

/* Factorize Newton matrix m for the iterate y1: OK, SINGULAR or EVAL (step_logic's _refactor;
 * numba_steps_kernel._refactor_matrix with the Python loop's equilibration) */
static int refactor(const struct phc_steps *w, int m, double t, double h, const double *y, const double *y1, double s)
{
    const int64_t n = w->n;
    double *a = w->lu + (int64_t)m * n * n;
    double *rs = w->eq + (int64_t)m * 2 * n, *cs = rs + n;
    double *matf = w->matf + 3 * m;
    w->ist[I_NFACT] += 1;
    stage_point(n, y, y1, s, h, w->xs, w->d);
    const double cj = 1.0 / (s * h);
    w->jacobian(t + s * h, w->xs, w->d, w->p, cj, w->jbuf);
    if (w->nend > 0)
        w->jacobian(t + h, y1, w->d, w->p, cj, w->ebuf);
    matf[2] = 0.0;
    if (!all_finite(w->njac, w->jbuf) || (w->nend > 0 && !all_finite(w->njac, w->ebuf)))
        return EVAL;
    memset(a, 0, (size_t)(n * n) * sizeof(double));
    for (int64_t k = 0; k < w->njac; ++k)
        a[w->jcols[k] * n + w->jrows[k]] += (w->nend > 0 && w->emask[k]) ? w->ebuf[k] : s * w->jbuf[k];
    /* columns: the nominal scale where the Newton test has one, else the largest entry to [1, 2);
     * then rows (phc.simulation.midpoint.equilibration) */
    for (int64_t j = 0; j < n; ++j) {
        double big = 0.0;
        for (int64_t i = 0; i < n; ++i)
            if (fabs(a[j * n + i]) > big)
                big = fabs(a[j * n + i]);
        cs[j] = power_of_two_below(big);
        if (w->weights != NULL && w->weights[j] > 0.0) {
            const double nominal = 1.0 / w->weights[j];
            if (nominal > 0.0 && isfinite(nominal))
                cs[j] = 1.0 / power_of_two_below(nominal);
        }
    }
    for (int64_t i = 0; i < n; ++i)
        rs[i] = 0.0;
    for (int64_t j = 0; j < n; ++j)
        for (int64_t i = 0; i < n; ++i)
            if (fabs(a[j * n + i]) * cs[j] > rs[i])
                rs[i] = fabs(a[j * n + i]) * cs[j];
    for (int64_t i = 0; i < n; ++i)
        rs[i] = power_of_two_below(rs[i]);
    for (int64_t j = 0; j < n; ++j)
        for (int64_t i = 0; i < n; ++i)
            a[j * n + i] *= rs[i] * cs[j];
    if (lu_factor(n, a, w->piv + (int64_t)m * n) != 0)
        return SINGULAR;
    lu_permutation(n, w->piv + (int64_t)m * n, w->perm + (int64_t)m * n);
    matf[0] = h;
    matf[1] = s;
    matf[2] = 1.0;
    w->ist[I_AGE0 + m] = 0;
    return OK;
}

/* One entry of the correction's size (correct): the running maxima of its size (times q, the
 * weights' quotient, when weighted), of |y1| + 1 and of a GGL multiplier's (alg 1) size. */
static inline void examine(double r, double y1, int weighted, double q, int8_t alg, double *size, double *scale,
                           double *algmax)
{
    double a = fabs(r);
    if (fabs(y1) + 1.0 > *scale)
        *scale = fabs(y1) + 1.0;
    if (weighted) {
        if (alg == 1 && a > *algmax)
            *algmax = a;
        a = a * q;
    }
    if (a > *size)
        *size = a;
}

/* The correction delta = -J^-1 F at y1 (into w->r) and its size in the Newton test's units: with
 * weights, a state against its scale or its size, whichever is larger, and the algebraic variables
 * but the GGL multipliers (algmask 1) relative to |y| + 1; else all relative to |y| + 1
 * (step_logic's _correct; numba_steps_kernel._correct; midpoint.StageSolver.correct) */
static int correct(const struct phc_steps *w, int m, double t, double h, const double *y, const double *y1, double s,
                   double *size_out, double *states_out, double *scale_out, int *finite_out)
{
    const int64_t n = w->n;
    const double *rs = w->eq + (int64_t)m * 2 * n, *cs = rs + n;
    double *r = w->r;
    w->ist[I_NFEV] += 1;
    *size_out = 0.0;
    *states_out = 0.0;
    *scale_out = 1.0;
    *finite_out = 1;
    if (!stage_residual(w, t, h, y, y1, s, r))
        return EVAL;
    /* delta = C (R J C)^-1 R (-F), the right-hand side gathered in the LU's row order (into d:
     * free once the residual is evaluated) */
    const int64_t *perm = w->perm + (int64_t)m * n;
    double *x = w->d;
    for (int64_t i = 0; i < n; ++i)
        x[i] = -r[perm[i]] * rs[perm[i]];
    lu_solve(n, w->lu + (int64_t)m * n * n, NULL, x);
    for (int64_t i = 0; i < n; ++i)
        r[i] = x[i] * cs[i];
    double size = 0.0, scale = 1.0, alg = 0.0;
    const int weighted = w->weights != NULL;
    /* the weights' quotients first, in a loop of their own that the compiler vectorizes (one
     * division an unknown is most of this function's own time); xs, the stage point, is free
     * once the residual is evaluated (without weights q is read, not used) */
    double *q = w->xs;
    if (weighted)
        quotients(n, w->weights, y1, q);
    const int finite = all_finite(n, r);
    /* the largest entries, in four running maxima (every fourth entry each), then the largest of
     * them: a maximum does not depend on the order (a NaN, never larger, is skipped either way),
     * and four short chains of comparisons wait less than one long one */
    double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0, c0 = 1.0, c1 = 1.0, c2 = 1.0, c3 = 1.0;
    double a0 = 0.0, a1 = 0.0, a2 = 0.0, a3 = 0.0;
    const int8_t *am = w->algmask;
    int64_t i = 0;
    for (; i + 3 < n; i += 4) {
        examine(r[i], y1[i], weighted, q[i], am[i], &s0, &c0, &a0);
        examine(r[i + 1], y1[i + 1], weighted, q[i + 1], am[i + 1], &s1, &c1, &a1);
        examine(r[i + 2], y1[i + 2], weighted, q[i + 2], am[i + 2], &s2, &c2, &a2);
        examine(r[i + 3], y1[i + 3], weighted, q[i + 3], am[i + 3], &s3, &c3, &a3);
    }
    for (; i < n; ++i)
        examine(r[i], y1[i], weighted, q[i], am[i], &s0, &c0, &a0);
    const double sizes[4] = {s0, s1, s2, s3}, scales[4] = {c0, c1, c2, c3}, algs[4] = {a0, a1, a2, a3};
    for (int k = 0; k < 4; ++k) {
        if (sizes[k] > size)
            size = sizes[k];
        if (scales[k] > scale)
            scale = scales[k];
        if (algs[k] > alg)
            alg = algs[k];
    }
    const double states = size;
    if (weighted) {
        if (alg / scale > size)
            size = alg / scale;
        scale = 1.0;
    }
    *size_out = size;
    *states_out = states;
    *scale_out = scale;
    *finite_out = finite;
    return OK;
}

/* The operations step_logic.newton calls (its _begin, _refactor, _correct, _precision) on this
 * loop's struct: the matrix's age and what it was factorized for, refactor, correct (the
 * correction in w->r; every correction here is in double precision, so `low` is always 0 and
 * step_logic's single-precision branches are never taken), and nothing to switch. */
static int op_begin(const struct phc_steps *w, int64_t m, double *h0, double *s0, int64_t *age)
{
    const double *matf = w->matf + 3 * m;
    w->ist[I_AGE0 + m] += 1;
    *h0 = matf[0];
    *s0 = matf[1];
    *age = w->ist[I_AGE0 + m];
    return matf[2] != 0.0;
}

static int64_t op_refactor(int64_t n, const struct phc_steps *w, int64_t m, double t, double h, const double *y,
                           const double *y1, double s)
{
    (void)n;
    return refactor(w, (int)m, t, h, y, y1, s);
}

static int64_t op_correct(int64_t n, const struct phc_steps *w, int64_t m, double t, double h, const double *y,
                          const double *y1, double s, double **delta, double *size, double *states, double *scale,
                          int *finite, int *low)
{
    (void)n;
    *delta = w->r;
    *low = 0;
    return correct(w, (int)m, t, h, y, y1, s, size, states, scale, finite);
}

static void op_precision(const struct phc_steps *w, int64_t event)
{
    (void)w;
    (void)event;
}

/* step_logic's _consistent: the velocities H is written in made consistent with the states. The C
 * loop does not run models that have such rows with the discrete gradient (phc.simulation.compiled_steps):
 * nothing to do. */
static void op_consistent(int64_t n, const struct phc_steps *w, double t, double *y)
{
    (void)n;
    (void)w;
    (void)t;
    (void)y;
}

/* step_logic's _watch (numba_steps_kernel._watch, the same operations in the same order): the
 * watched switching functions at the step's end, w_i = a_i + b_i v[k_i] with v the model's
 * events(t + h, y_new, (y_new - y)/h). 1 when one falls from above zero (wprev, the values at the
 * step's start) to zero or below, or a value of v is not finite: the step is handed back and the
 * driver locates the event (phc.simulation.compiled_steps.integrate). Else the values become the
 * next step's start; 0. A run without switching conditions (nwatch = 0) watches nothing. */
static int op_watch(int64_t n, const struct phc_steps *w, double t, double h, const double *y, const double *y_new)
{
    const int64_t nw = w->nwatch;
    if (nw == 0)
        return 0;
    for (int64_t i = 0; i < n; ++i)
        w->slope[i] = (y_new[i] - y[i]) / h;
    w->events(t + h, y_new, w->slope, w->p, w->vbuf);
    if (!all_finite(w->nev, w->vbuf))
        return 1;
    const double *a = w->wmap, *b = w->wmap + nw, *k = w->wmap + 2 * nw;
    int crossed = 0;
    for (int64_t i = 0; i < nw; ++i) {
        const double value = a[i] + b[i] * w->vbuf[(int64_t)k[i]];
        w->wnew[i] = value;
        if (w->wprev[i] > 0.0 && value <= 0.0)
            crossed = 1;
    }
    if (crossed)
        return 1;
    for (int64_t i = 0; i < nw; ++i)
        w->wprev[i] = w->wnew[i];
    return 0;
}

/* step_logic's _stage: one stage solve, the translated newton (defined after it) */
static int64_t op_stage(int64_t n, const struct phc_steps *w, int64_t m, double t, double h, const double *y,
                        const double *y1in, double s, double *out, int *ill);

/* step_logic's _advance (chunk's step of the run's method) and _far_from_singular (the monitor's
 * routine look), defined after the translated functions they call */
static int64_t op_advance(int64_t n, const struct phc_steps *w, double t, double h, const double *y, const double *guess,
                          double *out, int *ill);
static int op_far_from_singular(int64_t n, const struct phc_steps *w, double t, const double *y, const double *yp,
                                double hm);

/* ---- phc.simulation.step_logic, translated ------------------------------------------------
 * substeps, next_step, predictor_nodes, lagrange_weights, polynomial, extrapolate, predict,
 * looks, accept, newton, discrete_gradient, midpoint4 and chunk (the chunk loop) are not written
 * here, nor the library's entry phc_steps_chunk (chunk on the struct): phc.codegen.c_steps.source()
 * puts their translation (phc.codegen.c_translate, from the Python the other loops run) in place
 * of the next line. */
/* PHC_STEP_LOGIC */

static int64_t op_stage(int64_t n, const struct phc_steps *w, int64_t m, double t, double h, const double *y,
                        const double *y1in, double s, double *out, int *ill)
{
    return newton(n, w, m, w->c, t, h, y, y1in, s, out, ill);
}

/* step_logic's _advance: one step of the method ist[I_METHOD] (0 midpoint, 1 discrete gradient,
 * 2 midpoint4) from guess into out (numba_steps_kernel._advance); the outcome, *ill <- whether a
 * stage was ill-conditioned */
static int64_t op_advance(int64_t n, const struct phc_steps *w, double t, double h, const double *y, const double *guess,
                          double *out, int *ill)
{
    switch (w->ist[I_METHOD]) {
    case 1: {
        double best, scale;
        int64_t secants;
        return discrete_gradient(n, w->hamiltonian, w->energy_scale, w, w->c, w->ist[I_E], t, h, y, guess, w->p, out,
                                 ill, out, &best, &scale, w->y_half, &secants);
    }
    case 2: {
        int64_t nhist;
        const int64_t code = midpoint4(n, w->powers, w->energy_scale, w, w->c, t, h, y, guess, w->p, out, w->hist_t,
                                       w->hist_v, w->ist[I_HIST], w->algmask, ill, &nhist);
        w->ist[I_HIST] = nhist;
        return code;
    }
    default:
        return newton(n, w, 0, w->c, t, h, y, guess, 0.5, out, ill);
    }
}

/* ---- the monitor's routine look (numba_steps_kernel._monitor_ratio) ---------------------- */

/* step_logic's _far_from_singular, the routine look of the singularity monitor: 1 when the
 * equilibrated iteration matrix at (t, y, yp) (SingularityMonitor.ratio: cj = 1/hm) is clearly far
 * from singular (dense_lu.c's monitor_rcond and far_from_singular: the LAPACK-style 1-norm condition
 * estimate RCOND_MARGIN n times above the threshold), else 0: Python's monitor looks (its SVD
 * decides; the numba loop computes that SVD itself). */
static int op_far_from_singular(int64_t n, const struct phc_steps *w, double t, const double *y, const double *yp,
                                double hm)
{
    const double rcond = monitor_rcond(n, w->njac, w->jacobian, w->p, w->jrows, w->jcols, w->colscale, w->jbuf,
                                       w->mon, w->monpiv, w->monv, t, y, yp, hm);
    return far_from_singular(rcond, w->c[C_THRESHOLD], n);
}


/* The layout this file was written for, for the caller to check before the first chunk:
 * the ABI, the sizes of the state vectors, the indices the driver shares, sizeof(struct phc_steps). */
void phc_steps_layout(int64_t *out)
{
    const int64_t layout[] = {
        PHC_STEPS_ABI, I_NI, F_NF, C_NC,
        I_K, I_J, I_SUBSTEPS, I_STEPS, I_LAST_LOOK, I_HAS_MID, I_MAX_STEPS, I_STATUS, I_NFEV, I_NFACT, I_HIST,
        I_MONITOR, I_METHOD, I_CODE, I_ILL, I_E, I_NEND, I_NMID, I_LOWP, I_STRIKES,
        F_T, F_H, F_H_PREV, F_STEP,
        C_TOL, C_RATE, C_FLOOR, C_MAX_AGE, C_MAX_NEWTON, C_THRESHOLD, C_EVERY, C_ORDER, C_ZONE, C_STAGNATION,
        C_ORDER_ALG, C_BAL_TOL, C_MAX_SECANT, C_S_MIN, C_S_MAX, C_G1, C_G2, C_M0, C_M1, C_M2, C_RUN_ENERGY,
        ST_BUDGET, ST_DONE, ST_HARD, ST_LOOK, ST_MAXSTEPS, ST_EVENT, OK, FAIL, SINGULAR, EVAL, PASSIVITY,
        MAX_NODES, (int64_t)sizeof(struct phc_steps),
    };
    for (size_t i = 0; i < sizeof(layout) / sizeof(layout[0]); ++i)
        out[i] = layout[i];
}

/* The model's functions along a solution: at each of the `npts` points (t[i], ys[i], yps[i]) (rows of
 * n), H, the energy scale, the port powers (2), the position and velocity invariants (ninv, nvinv)
 * and the outputs (nout), into rows of the caller's arrays. What phc.simulation's `_evaluate_along`
 * calls once for a run's output points instead of six calls of the model's functions from Python
 * per point (phc/codegen/c_steps.py: along; a NULL function is skipped: H alone at many states is
 * what the energy sizes of the nominal scales need); the same functions, the same values to the bit. */
void phc_steps_along(phc_scalar_fn hamiltonian, phc_scalar_fn energy_scale, phc_powers_fn powers,
                     phc_invariants_fn invariants, phc_invariants_fn velocity_invariants, phc_powers_fn outputs,
                     int64_t n, int64_t npts, const double *t, const double *ys, const double *yps, const double *p,
                     int64_t ninv, int64_t nvinv, int64_t nout, double *H, double *scale, double *pw, double *inv,
                     double *vinv, double *outs)
{
    for (int64_t i = 0; i < npts; ++i) {
        const double *y = ys + i * n, *yp = yps + i * n;
        H[i] = hamiltonian(t[i], y, p);
        if (energy_scale)
            scale[i] = energy_scale(t[i], y, p);
        if (powers)
            powers(t[i], y, yp, p, pw + 2 * i);
        if (ninv && invariants)
            invariants(t[i], y, p, inv + i * ninv);
        if (nvinv && velocity_invariants)
            velocity_invariants(t[i], y, p, vinv + i * nvinv);
        if (nout && outputs)
            outputs(t[i], y, yp, p, outs + i * nout);
    }
}
