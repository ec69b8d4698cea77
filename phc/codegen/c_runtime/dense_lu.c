/* The dense LU with partial pivoting and the singularity monitor's routine look, written once for
 * phc's two C loops: the fixed-step methods' step loop (steps.c, phc/codegen/c_steps.py) and the
 * native IDA driver (ida_driver.c, phc/codegen/c_ida.py). Not compiled on its own: each of them has
 * the line PHC_DENSE_LU, which its module replaces with this text when it builds the library (after
 * the including file's <math.h>, <stdint.h>, <string.h> and its typedef phc_jacobian_fn).
 *
 * The routine look (monitor_rcond, far_from_singular) is the cheap first part of a look of
 * phc.simulation.monitor.SingularityMonitor: the iteration matrix F_y + F_yp/h equilibrated (rows,
 * then columns, to largest entry 1, twice: LAPACK's dgeequ twice, phc.simulation.equilibrate), its
 * LU, and the 1-norm condition estimate LAPACK's dgecon computes from it (Hager's method with
 * Higham's refinements). A look the estimate puts RCOND_MARGIN n times above the monitor's threshold
 * is clearly far from singular (monitor._far_from_singular gives 1/(n kappa_1), about a lower bound
 * of sigma_min/sigma_max there); any other look is Python's monitor's to make (its SVD decides).
 */

/* The routine look passes only where the 1-norm condition estimate is this factor (times n) above
 * the monitor's threshold (phc.simulation.monitor.RCOND_MARGIN, numba_steps_kernel._RCOND_MARGIN). */
#define RCOND_MARGIN 1e3

/* ---- vectors ------------------------------------------------------------------------------ */

static int all_finite(int64_t n, const double *v)
{
    /* the exponent field all ones (an infinity, a NaN) carries into the sign bit when one is added
     * to it: integer operations without an early exit, which the compiler vectorizes (every
     * entry is finite on the routine path, which reads them all anyway) */
    const uint64_t exponent = UINT64_C(0x7ff0000000000000), unit = UINT64_C(1) << 52;
    uint64_t carry = 0;
    for (int64_t i = 0; i < n; ++i) {
        uint64_t bits;
        memcpy(&bits, v + i, sizeof bits);
        carry |= (bits & exponent) + unit;
    }
    return (carry >> 63) == 0;
}

/* ---- dense LU with partial pivoting, column-major (a[j*n + i] is row i, column j) -------- */

/* LU = P A in place (L unit lower, U upper), piv[k] the row swapped with row k at step k;
 * 0, or k + 1 when the pivot of column k is exactly zero (LAPACK's info; scipy's splu refuses
 * such a matrix as singular). */
static inline __attribute__((always_inline)) int64_t lu_factor_body(int64_t n, double *restrict a,
                                                                    int64_t *restrict piv)
{
    for (int64_t k = 0; k < n; ++k) {
        double *ck = a + k * n;
        int64_t p = k;
        double big = fabs(ck[k]);
        for (int64_t i = k + 1; i < n; ++i)
            if (fabs(ck[i]) > big) {
                big = fabs(ck[i]);
                p = i;
            }
        piv[k] = p;
        if (big == 0.0)
            return k + 1;
        if (p != k)
            for (int64_t j = 0; j < n; ++j) {
                double tmp = a[j * n + k];
                a[j * n + k] = a[j * n + p];
                a[j * n + p] = tmp;
            }
        const double pivot = ck[k];
        for (int64_t i = k + 1; i < n; ++i)
            ck[i] /= pivot;
        for (int64_t j = k + 1; j < n; ++j) {   /* the rank-one update, column by column */
            double *cj = a + j * n;
            const double f = cj[k];
            if (f != 0.0)
                for (int64_t i = k + 1; i < n; ++i)
                    cj[i] -= ck[i] * f;
        }
    }
    return 0;
}

/* The AVX2 copies (here and lu_solve's below): the library must run on any x86-64 CPU (no
 * -march), so a copy for AVX2's four doubles a vector instruction is compiled beside the
 * baseline one (SSE2's two) and chosen when the CPU has AVX2 (__builtin_cpu_supports reads the
 * CPU's features libgcc found once: no state of this file). Same operations in the same order
 * and no fused multiply-add (the target adds no FMA and the flags forbid contraction): the same
 * IEEE results on either path. */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(PHC_NO_AVX2_DISPATCH)
#define PHC_AVX2_DISPATCH 1
__attribute__((target("avx2"))) static int64_t lu_factor_avx2(int64_t n, double *a, int64_t *piv)
{
    return lu_factor_body(n, a, piv);
}
#endif

static int64_t lu_factor(int64_t n, double *a, int64_t *piv)
{
#ifdef PHC_AVX2_DISPATCH
    if (__builtin_cpu_supports("avx2"))
        return lu_factor_avx2(n, a, piv);
#endif
    return lu_factor_body(n, a, piv);
}

/* x <- A^-1 x from the LU of lu_factor; piv NULL: x is P x already (gathered by
 * lu_permutation's order).
 *
 * Four columns at a time: each entry of x takes the same operations in the same order as
 * column by column (x_i - l_i0 x_0, then - l_i1 x_1, ...), with a quarter of the passes over x
 * and of the waits for the entries the next columns need. The back substitution does the rows
 * the next four columns divide first, so that their divisions (the slowest operation here,
 * one after the other) overlap with the rest of the pass. (Skipping the rows where the four
 * columns hold only zeros saves nothing measurable at the slider-crank's 83 unknowns: the
 * factors fill in.) Written once, compiled twice below (SSE2, and AVX2 where the CPU has it). */
static inline __attribute__((always_inline)) void lu_solve_body(int64_t n, const double *restrict a,
                                                                const int64_t *restrict piv, double *restrict x)
{
    if (piv != NULL)
        for (int64_t k = 0; k < n; ++k)
            if (piv[k] != k) {
                double tmp = x[k];
                x[k] = x[piv[k]];
                x[piv[k]] = tmp;
            }
    int64_t j = 0;
    for (; j + 3 < n; j += 4) {  /* L z = P x: columns j ... j + 3, then their rows j + 4 ... */
        const double *c0 = a + j * n, *c1 = c0 + n, *c2 = c1 + n, *c3 = c2 + n;
        const double x0 = x[j];
        const double x1 = x[j + 1] = x[j + 1] - c0[j + 1] * x0;
        const double x2 = x[j + 2] = (x[j + 2] - c0[j + 2] * x0) - c1[j + 2] * x1;
        const double x3 = x[j + 3] = ((x[j + 3] - c0[j + 3] * x0) - c1[j + 3] * x1) - c2[j + 3] * x2;
        for (int64_t i = j + 4; i < n; ++i)
            x[i] = (((x[i] - c0[i] * x0) - c1[i] * x1) - c2[i] * x2) - c3[i] * x3;
    }
    for (; j < n; ++j) {  /* the last n mod 4 columns */
        const double *c0 = a + j * n;
        for (int64_t i = j + 1; i < n; ++i)
            x[i] = x[i] - c0[i] * x[j];
    }
    for (j = n - 1; j >= 3; j -= 4) {  /* U x = z: columns j ... j - 3, then their rows ... j - 4 */
        const double *c0 = a + j * n, *c1 = c0 - n, *c2 = c1 - n, *c3 = c2 - n;
        const double x0 = x[j] = x[j] / c0[j];
        const double x1 = x[j - 1] = (x[j - 1] - c0[j - 1] * x0) / c1[j - 1];
        const double x2 = x[j - 2] = ((x[j - 2] - c0[j - 2] * x0) - c1[j - 2] * x1) / c2[j - 2];
        const double x3 = x[j - 3] = (((x[j - 3] - c0[j - 3] * x0) - c1[j - 3] * x1) - c2[j - 3] * x2) / c3[j - 3];
        const int64_t next = j - 7 > 0 ? j - 7 : 0;  /* the next four columns' rows first */
        for (int64_t i = next; i < j - 3; ++i)
            x[i] = (((x[i] - c0[i] * x0) - c1[i] * x1) - c2[i] * x2) - c3[i] * x3;
        for (int64_t i = 0; i < next; ++i)
            x[i] = (((x[i] - c0[i] * x0) - c1[i] * x1) - c2[i] * x2) - c3[i] * x3;
    }
    for (; j >= 0; --j) {  /* the first n mod 4 columns */
        const double *c0 = a + j * n;
        x[j] = x[j] / c0[j];
        for (int64_t i = 0; i < j; ++i)
            x[i] = x[i] - c0[i] * x[j];
    }
}

/* The triangular solves are most of a step's time (seven a step on the slider-crank): their
 * AVX2 copy takes about 0.8x the time of the baseline one. */
#ifdef PHC_AVX2_DISPATCH
__attribute__((target("avx2"))) static void lu_solve_avx2(int64_t n, const double *a, const int64_t *piv, double *x)
{
    lu_solve_body(n, a, piv, x);
}
#endif

static void lu_solve(int64_t n, const double *a, const int64_t *piv, double *x)
{
#ifdef PHC_AVX2_DISPATCH
    if (__builtin_cpu_supports("avx2")) {
        lu_solve_avx2(n, a, piv, x);
        return;
    }
#endif
    lu_solve_body(n, a, piv, x);
}

/* x <- (LU)^-T x = L^-T U^-T x from the LU of lu_factor, without its row interchanges (what LAPACK's
 * dgecon multiplies by: the 1-norm of A^-1 = (P^T L U)^-1 is that of U^-1 L^-1, whose columns are
 * A^-1's permuted) */
static void lu_solve_transposed(int64_t n, const double *a, double *x)
{
    for (int64_t j = 0; j < n; ++j) {       /* U^T z = x */
        const double *cj = a + j * n;
        double acc = x[j];
        for (int64_t i = 0; i < j; ++i)
            acc -= cj[i] * x[i];
        x[j] = acc / cj[j];
    }
    for (int64_t j = n - 1; j >= 0; --j) {  /* L^T w = z */
        const double *cj = a + j * n;
        double acc = x[j];
        for (int64_t i = j + 1; i < n; ++i)
            acc -= cj[i] * x[i];
        x[j] = acc;
    }
}

static double norm1(int64_t n, const double *x)
{
    double s = 0.0;
    for (int64_t i = 0; i < n; ++i)
        s += fabs(x[i]);
    return s;
}

static int64_t argmax_abs(int64_t n, const double *x)
{
    int64_t j = 0;
    for (int64_t i = 1; i < n; ++i)
        if (fabs(x[i]) > fabs(x[j]))
            j = i;
    return j;
}

/* sign(x) as LAPACK's dlacn2 takes it: 1 for x >= 0, else -1 */
static double sign_of(double x)
{
    return x >= 0.0 ? 1.0 : -1.0;
}

/* An estimate of ||A^-1||_1 from the LU of A (lu_factor), a lower bound within a small factor in
 * practice: LAPACK's dgecon, step for step — Hager's method with Higham's refinements as its dlacn2
 * runs it (N. J. Higham, "FORTRAN codes for estimating the one-norm of a real or complex matrix",
 * ACM TOMS 14, 1988), on U^-1 L^-1 as dgecon applies it (no row interchanges: the same norm, the
 * same iterates as LAPACK's), so that the estimate is LAPACK's up to the rounding of the LU and of
 * the solves (Python's monitor calls dgecon: phc.simulation.monitor._far_from_singular). x and
 * sgn: n entries of scratch each. */
static double inverse_norm1(int64_t n, const double *a, double *x, double *sgn)
{
    for (int64_t i = 0; i < n; ++i)
        x[i] = 1.0 / (double)n;
    lu_solve(n, a, NULL, x);
    if (n == 1)
        return fabs(x[0]);
    double est = norm1(n, x);
    for (int64_t i = 0; i < n; ++i)
        x[i] = sgn[i] = sign_of(x[i]);
    lu_solve_transposed(n, a, x);
    int64_t j = argmax_abs(n, x);
    for (int iter = 2;; ++iter) {
        for (int64_t i = 0; i < n; ++i)
            x[i] = 0.0;
        x[j] = 1.0;
        lu_solve(n, a, NULL, x);
        const double old = est;
        est = norm1(n, x);
        int same = 1;
        for (int64_t i = 0; i < n; ++i)
            if (sign_of(x[i]) != sgn[i]) {
                same = 0;
                break;
            }
        if (same || est <= old)  /* a repeated sign vector (converged), or cycling */
            break;
        for (int64_t i = 0; i < n; ++i)
            x[i] = sgn[i] = sign_of(x[i]);
        lu_solve_transposed(n, a, x);
        const int64_t last = j;
        j = argmax_abs(n, x);
        if (!(x[last] != fabs(x[j]) && iter < 5))  /* (dlacn2 compares x[last] itself, not |x[last]|) */
            break;
    }
    double altsgn = 1.0;  /* an alternating-sign vector catches what the iteration misses */
    for (int64_t i = 0; i < n; ++i) {
        x[i] = altsgn * (1.0 + (double)i / (double)(n - 1));
        altsgn = -altsgn;
    }
    lu_solve(n, a, NULL, x);
    const double alt = 2.0 * (norm1(n, x) / (double)(3 * n));
    return alt > est ? alt : est;
}

/* ---- the singularity monitor's routine look ------------------------------------------------ */

/* The reciprocal 1-norm condition estimate of the equilibrated iteration matrix F_y + F_yp/hm at
 * (t, y, yp) (SingularityMonitor._equilibrated: c_j = 1/hm, hm at least 1e-300), columns first
 * multiplied by colscale where it is not NULL; 0 where the Jacobian is not finite there or its LU
 * meets an exactly zero pivot (Python's monitor then looks). Scratch: jbuf (njac), a (n x n), piv
 * (n), v (3n). The Jacobian's pattern is jrows, jcols (njac entries). */
static double monitor_rcond(int64_t n, int64_t njac, phc_jacobian_fn jacobian, const double *p,
                            const int64_t *jrows, const int64_t *jcols, const double *colscale, double *jbuf,
                            double *a, int64_t *piv, double *v, double t, const double *y, const double *yp,
                            double hm)
{
    double *rowmax = v, *x = v + n, *sgn = v + 2 * n;
    jacobian(t, y, yp, p, 1.0 / (hm > 1e-300 ? hm : 1e-300), jbuf);
    if (!all_finite(njac, jbuf))
        return 0.0;
    memset(a, 0, (size_t)(n * n) * sizeof(double));
    for (int64_t k = 0; k < njac; ++k)
        a[jcols[k] * n + jrows[k]] = jbuf[k];
    if (colscale != NULL)  /* scaled variables y/s: columns times s */
        for (int64_t j = 0; j < n; ++j)
            for (int64_t i = 0; i < n; ++i)
                a[j * n + i] *= colscale[j];
    for (int sweep = 0; sweep < 2; ++sweep) {
        for (int64_t i = 0; i < n; ++i)
            rowmax[i] = 0.0;
        for (int64_t j = 0; j < n; ++j)
            for (int64_t i = 0; i < n; ++i)
                if (fabs(a[j * n + i]) > rowmax[i])
                    rowmax[i] = fabs(a[j * n + i]);
        for (int64_t j = 0; j < n; ++j)
            for (int64_t i = 0; i < n; ++i)
                if (rowmax[i] > 0.0)
                    a[j * n + i] /= rowmax[i];
        for (int64_t j = 0; j < n; ++j) {
            double big = 0.0;
            for (int64_t i = 0; i < n; ++i)
                if (fabs(a[j * n + i]) > big)
                    big = fabs(a[j * n + i]);
            if (big > 0.0)
                for (int64_t i = 0; i < n; ++i)
                    a[j * n + i] /= big;
        }
    }
    double anorm = 0.0;
    for (int64_t j = 0; j < n; ++j) {
        const double col = norm1(n, a + j * n);
        if (col > anorm)
            anorm = col;
    }
    if (lu_factor(n, a, piv) != 0 || anorm == 0.0)
        return 0.0;
    const double ainvnm = inverse_norm1(n, a, x, sgn);
    return ainvnm != 0.0 ? (1.0 / ainvnm) / anorm : 0.0;  /* dgecon's */
}

/* Whether a routine look of estimate rcond (monitor_rcond) at n unknowns is clearly far from the
 * monitor's threshold (monitor._far_from_singular's test): else Python's monitor looks. */
static int far_from_singular(double rcond, double threshold, int64_t n)
{
    return isfinite(rcond) && rcond >= threshold * (double)n * RCOND_MARGIN;
}
