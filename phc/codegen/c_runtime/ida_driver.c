/* phc's native IDA driver: SUNDIALS IDA (public C API, version 6 or 7) calling a model's compiled
 * residual and Jacobian directly, stepping in a C loop.
 *
 * Built by phc/codegen/c_ida.py against the machine's own SUNDIALS (headers and libraries it finds:
 * $SUNDIALS_DIR, $CONDA_PREFIX, pkg-config, /usr, /usr/local, Homebrew); a run on the C back end uses it
 * through phc/simulation/ida_native.py. The numerics are IDA's: BDF of variable order and step, the dense
 * LU of SUNDIALS' own linear solver, the tolerances, the id vector and the maximum order phc's
 * phc.simulation.ida chooses (passed in by the caller; nothing here chooses a tolerance).
 *
 * One call of phc_ida_advance takes up to `budget` of IDA's steps (IDASolve in IDA_ONE_STEP mode, with
 * the run's end as IDA's stop time), writes the outputs at the output times the steps pass (IDA's own
 * interpolation, IDAGetDky: y and y') and each step's end time and size into the
 * caller's arrays, and returns; the Python side runs phc's singularity monitor, progress, max_steps and
 * its choice of the maximum order between calls. The residual and Jacobian are the model library's
 * phc_residual and phc_jacobian (phc/codegen/c_printer.py), called through function pointers.
 *
 * A model that cannot be evaluated at IDA's trial point (a value that is not finite) is a recoverable
 * failure for IDA (the callbacks return 1: IDA retries the step shorter, as phc.simulation.ida's Python
 * callbacks make it by returning NaN); the latest such point is kept (t_failed, y_failed, yp_failed) so
 * that Python can evaluate it again through phc's guard and give the located error.
 *
 * The singularity monitor's routine look (phc_ida_watch switches it on): after every `cadence` steps
 * the driver looks at the iteration matrix itself, with the fixed-step loop's routine look (dense_lu.c,
 * put at the line PHC_DENSE_LU below when the library is built: the equilibrated matrix's LU and
 * LAPACK-style 1-norm condition estimate). A look that finds the matrix clearly far from singular is
 * recorded (time, step, ratio 1/(n kappa_1), state: Python's monitor replays it between calls as if it
 * had looked, phc.simulation.monitor.SingularityMonitor.routine_looks) and sets the next cadence; any
 * other look ends the call (PHC_LOOK) without being recorded, and Python's monitor makes it, as the
 * step hook does without the driver (phc.simulation.ida._StepHook._look): a look the estimate does not
 * clear; one whose ratio with the two looks before brackets a minimum of the conditioning, where the
 * monitor's search between them (run here first) meets a point the estimate does not clear; and one
 * where IDA crawls (its step cannot reach the end within max_steps). Those decisions, the search, its
 * interpolant and the cadence are phc.simulation.look_cadence's functions (cadence_after,
 * brackets_minimum, crawls, golden_search, hermite), translated by phc.codegen.c_translate at the line
 * PHC_LOOK_LOGIC below: written once, in Python, which the step hook and the monitor run.
 *
 * Re-entrant: no static mutable state. Everything a run uses is in its struct phc_ida (IDA's user data),
 * allocated by phc_ida_create and released by phc_ida_free.
 */

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <ida/ida.h>
#include <nvector/nvector_serial.h>
#include <sundials/sundials_config.h>
#include <sundials/sundials_types.h>
#include <sunlinsol/sunlinsol_dense.h>
#include <sunmatrix/sunmatrix_dense.h>

#if !defined(SUNDIALS_DOUBLE_PRECISION)
#error "phc's IDA driver needs SUNDIALS built in double precision (the model's functions are in double)"
#endif

#if SUNDIALS_VERSION_MAJOR < 6
#error "phc's IDA driver needs SUNDIALS 6 or later (SUNContext)"
#endif

#if SUNDIALS_VERSION_MAJOR < 7
typedef realtype phc_real;
#else
typedef sunrealtype phc_real;
#endif

#define PHC_IDA_ABI 2

typedef void (*phc_residual_fn)(double t, const double *y, const double *yp, const double *p, double *out);
typedef void (*phc_jacobian_fn)(double t, const double *y, const double *yp, const double *p, double cj,
                                double *out);

/* PHC_DENSE_LU */

/* The workspace of the translated search (look_cadence.golden_search's `ws`): the run's driver, and
 * its operation, the conditioning ratio at a time between the last looks (defined below). */
struct phc_ida;
struct phc_steps {
    struct phc_ida *w;
};
static double op_ratio_at_time(const struct phc_steps *ws, double t, int *below, int *unknown);

/* PHC_LOOK_LOGIC */

/* what phc_ida_advance returns (besides IDA's negative flags, passed on) */
enum { PHC_BUDGET = 0, PHC_DONE = 1, PHC_LOOK = 2 };

/* the routine look's integer state li[] (phc.simulation.ida_native: LI_*): the cadence, the steps since
 * the last look, the base cadence, the run's steps before the call, the step the crawl check is next
 * asked at, max_steps, the looks recorded in the call, why the call ended at a look (LOOK_*), the
 * record's capacity, the most iterations of the search between looks */
enum { LI_CADENCE, LI_SINCE, LI_BASE, LI_STEPS, LI_NEXT_CHECK, LI_MAX_STEPS, LI_LOOKS, LI_FLAG, LI_CAPACITY,
       LI_ITERATIONS, LI_N };
/* its float state lf[]: the monitor's threshold, its step floor h_floor, the run's end, the ratio of
 * the last look (NaN: none), the times and ratios of the last two looks, oldest first (NaN: none) */
enum { LF_THRESHOLD, LF_H_FLOOR, LF_T_END, LF_LAST_RATIO, LF_T0, LF_R0, LF_T1, LF_R1, LF_N };
/* why a look ends the call (li[LI_FLAG]) */
enum { LOOK_NONE, LOOK_NOT_CLEAR, LOOK_MINIMUM, LOOK_CRAWL };

#define PHC_MESSAGE 512

struct phc_ida {
    int64_t n, njac;
    phc_residual_fn residual;
    phc_jacobian_fn jacobian;
    const double *p;                 /* the caller's parameters (kept alive by the caller) */
    int64_t *jrows, *jcols;          /* njac: the Jacobian's pattern (copies) */
    double *jbuf;                    /* njac: the Jacobian's values */
    double *y_failed, *yp_failed;    /* n each: the latest point the model could not be evaluated at */
    double t_failed;
    int64_t nres, njacs, failures;   /* residual and Jacobian evaluations; non-finite evaluations */
    int failed_last;                 /* the latest evaluation was not finite */
    double cj;                       /* alpha/h of the latest Jacobian */
    SUNContext ctx;
    void *mem;
    N_Vector yy, yp, id, atol, tmp, tmp2;
    SUNMatrix A;
    SUNLinearSolver LS;
    char message[PHC_MESSAGE];       /* IDA's latest error message */
    /* the routine look (phc_ida_watch; li NULL: off): its state and record (the caller's arrays) and
     * scratch */
    int64_t *li;
    double *lf, *look_t, *look_h, *look_r, *look_y, *look_yp;
    double *last_h, *last_y, *last_yp; /* 3, 3n, 3n: steps and states of the last two looks, then this one */
    double last_t[3];                /* their times (the search's) */
    double *sy, *syp;                /* n each: a state the search looks at */
    double *mon, *monv, *mjbuf;      /* n x n, 3n, njac */
    int64_t *monpiv;                 /* n */
};

static void fail_at(struct phc_ida *w, double t, const double *y, const double *yp)
{
    w->failures += 1;
    w->failed_last = 1;
    /* keep the first failure located in finite inputs (a NaN iterate after a failed one says nothing new) */
    if (all_finite(w->n, y) && all_finite(w->n, yp)) {
        w->t_failed = t;
        memcpy(w->y_failed, y, (size_t)w->n * sizeof(double));
        memcpy(w->yp_failed, yp, (size_t)w->n * sizeof(double));
    }
}

static int residual_cb(phc_real t, N_Vector yy, N_Vector yp, N_Vector rr, void *data)
{
    struct phc_ida *w = (struct phc_ida *)data;
    const double *y = N_VGetArrayPointer(yy), *ydot = N_VGetArrayPointer(yp);
    double *r = N_VGetArrayPointer(rr);
    w->nres += 1;
    w->residual(t, y, ydot, w->p, r);
    if (!all_finite(w->n, r)) {
        fail_at(w, t, y, ydot);
        return 1;                    /* recoverable: IDA retries with a shorter step */
    }
    w->failed_last = 0;
    return 0;
}

static int jacobian_cb(phc_real t, phc_real cj, N_Vector yy, N_Vector yp, N_Vector rr, SUNMatrix J, void *data,
                       N_Vector t1, N_Vector t2, N_Vector t3)
{
    struct phc_ida *w = (struct phc_ida *)data;
    const double *y = N_VGetArrayPointer(yy), *ydot = N_VGetArrayPointer(yp);
    (void)rr; (void)t1; (void)t2; (void)t3;
    w->njacs += 1;
    w->cj = cj;
    w->jacobian(t, y, ydot, w->p, cj, w->jbuf);
    if (!all_finite(w->njac, w->jbuf)) {
        fail_at(w, t, y, ydot);
        return 1;
    }
    /* IDA zeroes a matrix-based linear solver's J before calling this: scatter the pattern's entries */
    double *a = SUNDenseMatrix_Data(J);
    const sunindextype ld = SUNDenseMatrix_Rows(J);
    for (int64_t k = 0; k < w->njac; ++k)
        a[w->jrows[k] + w->jcols[k] * ld] = w->jbuf[k];
    return 0;
}

static void keep_message(struct phc_ida *w, const char *msg)
{
    if (msg == NULL)
        return;
    strncpy(w->message, msg, PHC_MESSAGE - 1);
    w->message[PHC_MESSAGE - 1] = '\0';
}

#if SUNDIALS_VERSION_MAJOR < 7
static void error_cb(int code, const char *module, const char *function, char *msg, void *data)
{
    (void)code; (void)module; (void)function;
    keep_message((struct phc_ida *)data, msg);   /* kept, not printed: phc words the failure */
}
#else
static void error_cb(int line, const char *function, const char *file, const char *msg, SUNErrCode code,
                     void *data, SUNContext ctx)
{
    (void)line; (void)function; (void)file; (void)code; (void)ctx;
    keep_message((struct phc_ida *)data, msg);
}
#endif

void phc_ida_free(struct phc_ida *w)
{
    if (w == NULL)
        return;
    if (w->mem != NULL)
        IDAFree(&w->mem);
    if (w->LS != NULL)
        SUNLinSolFree(w->LS);
    if (w->A != NULL)
        SUNMatDestroy(w->A);
    N_Vector vs[6] = {w->yy, w->yp, w->id, w->atol, w->tmp, w->tmp2};
    for (int i = 0; i < 6; ++i)
        if (vs[i] != NULL)
            N_VDestroy(vs[i]);
    if (w->ctx != NULL)
        SUNContext_Free(&w->ctx);
    free(w->jrows);
    free(w->jcols);
    free(w->jbuf);
    free(w->y_failed);
    free(w->yp_failed);
    free(w->mon);
    free(w->monv);
    free(w->mjbuf);
    free(w->monpiv);
    free(w->sy);
    free(w->syp);
    free(w);
}

static void copy_in(N_Vector v, const double *x, int64_t n)
{
    memcpy(N_VGetArrayPointer(v), x, (size_t)n * sizeof(double));
}

/* A run's IDA at (t0, y0, yp0), consistent (phc's Python code makes them so; IDACalcIC is not called):
 * relative tolerance rtol, absolute tolerances atol[n], id[n] (1 differential, 0 algebraic: IDASetId),
 * maximum order, IDA's stop time t_stop, first step h0 (0: IDA's estimate), at most max_steps steps.
 * NULL when SUNDIALS refuses (status[0] the step that failed, 1-based). */
struct phc_ida *phc_ida_create(int64_t n, int64_t njac, phc_residual_fn residual, phc_jacobian_fn jacobian,
                               const double *p, const int64_t *jrows, const int64_t *jcols, double t0,
                               const double *y0, const double *yp0, double rtol, const double *atol,
                               const double *id, int64_t max_order, double t_stop, double h0, int64_t max_steps,
                               int64_t *status)
{
    struct phc_ida *w = (struct phc_ida *)calloc(1, sizeof *w);
    int step = 1;
    if (w == NULL)
        goto fail;
    w->n = n;
    w->njac = njac;
    w->residual = residual;
    w->jacobian = jacobian;
    w->p = p;
    w->jrows = (int64_t *)malloc((size_t)(njac > 0 ? njac : 1) * sizeof(int64_t));
    w->jcols = (int64_t *)malloc((size_t)(njac > 0 ? njac : 1) * sizeof(int64_t));
    w->jbuf = (double *)malloc((size_t)(njac > 0 ? njac : 1) * sizeof(double));
    w->y_failed = (double *)calloc((size_t)n, sizeof(double));
    w->yp_failed = (double *)calloc((size_t)n, sizeof(double));
    w->mon = (double *)malloc((size_t)(n * n) * sizeof(double));
    w->monv = (double *)malloc((size_t)(3 * n) * sizeof(double));
    w->mjbuf = (double *)malloc((size_t)(njac > 0 ? njac : 1) * sizeof(double));
    w->monpiv = (int64_t *)malloc((size_t)n * sizeof(int64_t));
    w->sy = (double *)malloc((size_t)n * sizeof(double));
    w->syp = (double *)malloc((size_t)n * sizeof(double));
    if (!w->jrows || !w->jcols || !w->jbuf || !w->y_failed || !w->yp_failed || !w->mon || !w->monv || !w->mjbuf
        || !w->monpiv || !w->sy || !w->syp)
        goto fail;
    memcpy(w->jrows, jrows, (size_t)njac * sizeof(int64_t));
    memcpy(w->jcols, jcols, (size_t)njac * sizeof(int64_t));
    step = 2;
#if SUNDIALS_VERSION_MAJOR < 7
    if (SUNContext_Create(NULL, &w->ctx) != 0)
        goto fail;
#else
    if (SUNContext_Create(SUN_COMM_NULL, &w->ctx) != 0)
        goto fail;
    SUNContext_ClearErrHandlers(w->ctx);
    SUNContext_PushErrHandler(w->ctx, error_cb, w);
#endif
    step = 3;
    w->yy = N_VNew_Serial((sunindextype)n, w->ctx);
    w->yp = N_VNew_Serial((sunindextype)n, w->ctx);
    w->id = N_VNew_Serial((sunindextype)n, w->ctx);
    w->atol = N_VNew_Serial((sunindextype)n, w->ctx);
    w->tmp = N_VNew_Serial((sunindextype)n, w->ctx);
    w->tmp2 = N_VNew_Serial((sunindextype)n, w->ctx);
    if (!w->yy || !w->yp || !w->id || !w->atol || !w->tmp || !w->tmp2)
        goto fail;
    copy_in(w->yy, y0, n);
    copy_in(w->yp, yp0, n);
    copy_in(w->id, id, n);
    copy_in(w->atol, atol, n);
    step = 4;
    w->mem = IDACreate(w->ctx);
    if (w->mem == NULL)
        goto fail;
#if SUNDIALS_VERSION_MAJOR < 7
    if (IDASetErrHandlerFn(w->mem, error_cb, w) != IDA_SUCCESS)
        goto fail;
#endif
    step = 5;
    if (IDAInit(w->mem, residual_cb, t0, w->yy, w->yp) != IDA_SUCCESS)
        goto fail;
    step = 6;
    if (IDASetUserData(w->mem, w) != IDA_SUCCESS || IDASVtolerances(w->mem, rtol, w->atol) != IDA_SUCCESS)
        goto fail;
    step = 7;
    w->A = SUNDenseMatrix((sunindextype)n, (sunindextype)n, w->ctx);
    w->LS = w->A ? SUNLinSol_Dense(w->yy, w->A, w->ctx) : NULL;
    if (!w->LS || IDASetLinearSolver(w->mem, w->LS, w->A) != IDA_SUCCESS || IDASetJacFn(w->mem, jacobian_cb) != IDA_SUCCESS)
        goto fail;
    step = 8;
    if (IDASetId(w->mem, w->id) != IDA_SUCCESS || IDASetMaxOrd(w->mem, (int)max_order) != IDA_SUCCESS
        || IDASetMaxNumSteps(w->mem, (long int)max_steps) != IDA_SUCCESS
        || IDASetStopTime(w->mem, t_stop) != IDA_SUCCESS)
        goto fail;
    if (h0 > 0.0 && IDASetInitStep(w->mem, h0) != IDA_SUCCESS)
        goto fail;
    status[0] = 0;
    return w;
fail:
    status[0] = step;
    phc_ida_free(w);
    return NULL;
}

/* Switch the routine look on (li not NULL) or off: its state li[LI_N], lf[LF_N] and the record of the
 * looks it passes, of li[LI_CAPACITY] looks (times, steps, ratios; states y, yp: capacity x n each), and
 * the steps and states of the monitor's last two looks (last_h: 3, last_y, last_yp: 3 x n, the first two
 * rows theirs, oldest first) are the caller's arrays, read and written by each phc_ida_advance. */
void phc_ida_watch(struct phc_ida *w, int64_t *li, double *lf, double *look_t, double *look_h, double *look_r,
                   double *look_y, double *look_yp, double *last_h, double *last_y, double *last_yp)
{
    w->last_h = last_h;
    w->last_y = last_y;
    w->last_yp = last_yp;
    w->li = li;
    w->lf = lf;
    w->look_t = look_t;
    w->look_h = look_h;
    w->look_r = look_r;
    w->look_y = look_y;
    w->look_yp = look_yp;
}

/* look_cadence.golden_search's operation: the conditioning ratio at time t on the cubic Hermite interpolant
 * of the last three looks (SingularityMonitor._state_at: look_cadence.hermite between the two looks around t,
 * at the later one's step), where the routine look clears it; else *unknown (Python's monitor searches). */
static double op_ratio_at_time(const struct phc_steps *ws, double t, int *below, int *unknown)
{
    struct phc_ida *w = ws->w;
    const int64_t n = w->n;
    const int64_t i = t <= w->last_t[1] ? 0 : 1;
    hermite(n, w->last_t[i], w->last_y + i * n, w->last_yp + i * n, w->last_t[i + 1], w->last_y + (i + 1) * n,
            w->last_yp + (i + 1) * n, t, w->sy, w->syp);
    const double rcond = monitor_rcond(n, w->njac, w->jacobian, w->p, w->jrows, w->jcols, NULL, w->mjbuf, w->mon,
                                       w->monpiv, w->monv, t, w->sy, w->syp, w->last_h[i + 1]);
    *below = 0;
    *unknown = !far_from_singular(rcond, w->lf[LF_THRESHOLD], n);
    return *unknown ? NAN : rcond / (double)n;
}

/* The routine look after a step of size h to IDA's state at t (the run's `steps` steps): LOOK_NONE
 * when it is clearly far from singular and recorded (the next cadence set), else why Python's monitor
 * must look (nothing recorded, nothing changed). As _StepHook._look: the monitor's check at
 * max(h, h_floor), its minimum search, the crawl check with h, then the cadence. */
static int routine_look(struct phc_ida *w, double t, double h, int64_t steps)
{
    int64_t *li = w->li;
    double *lf = w->lf;
    const int64_t n = w->n;
    const double *y = N_VGetArrayPointer(w->yy), *yp = N_VGetArrayPointer(w->yp);
    const double hm = h >= lf[LF_H_FLOOR] ? h : lf[LF_H_FLOOR];
    const double rcond = monitor_rcond(n, w->njac, w->jacobian, w->p, w->jrows, w->jcols, NULL, w->mjbuf, w->mon,
                                       w->monpiv, w->monv, t, y, yp, hm);
    if (!far_from_singular(rcond, lf[LF_THRESHOLD], n))
        return LOOK_NOT_CLEAR;
    const double ratio = rcond / (double)n;  /* monitor._far_from_singular's value */
    if (brackets_minimum(lf[LF_T0], lf[LF_R0], lf[LF_T1], lf[LF_R1], t, ratio)) {
        /* the monitor's search for the minimum between the last three looks (SingularityMonitor.watch),
         * while every point it looks at is clearly far from singular */
        struct phc_steps ws = {w};
        double t_found, r_found;
        w->last_t[0] = lf[LF_T0];
        w->last_t[1] = lf[LF_T1];
        w->last_t[2] = t;
        w->last_h[2] = hm;
        memcpy(w->last_y + 2 * n, y, (size_t)n * sizeof(double));
        memcpy(w->last_yp + 2 * n, yp, (size_t)n * sizeof(double));
        if (golden_search(&ws, lf[LF_T0], t, lf[LF_THRESHOLD], li[LI_ITERATIONS], lf[LF_R0], ratio, 0, &t_found,
                          &r_found) != 0)
            return LOOK_MINIMUM;
    }
    if (crawls(h, t, lf[LF_T_END], steps, li[LI_MAX_STEPS], li[LI_NEXT_CHECK]))
        return LOOK_CRAWL;
    const int64_t k = li[LI_LOOKS]++;
    w->look_t[k] = t;
    w->look_h[k] = hm;
    w->look_r[k] = ratio;
    memcpy(w->look_y + k * n, y, (size_t)n * sizeof(double));
    memcpy(w->look_yp + k * n, yp, (size_t)n * sizeof(double));
    lf[LF_T0] = lf[LF_T1];
    lf[LF_R0] = lf[LF_R1];
    lf[LF_T1] = t;
    lf[LF_R1] = ratio;
    w->last_h[0] = w->last_h[1];
    w->last_h[1] = hm;
    memcpy(w->last_y, w->last_y + n, (size_t)n * sizeof(double));
    memcpy(w->last_yp, w->last_yp + n, (size_t)n * sizeof(double));
    memcpy(w->last_y + n, y, (size_t)n * sizeof(double));
    memcpy(w->last_yp + n, yp, (size_t)n * sizeof(double));
    li[LI_CADENCE] = cadence_after(li[LI_CADENCE], li[LI_BASE], lf[LF_LAST_RATIO], ratio);
    lf[LF_LAST_RATIO] = ratio;
    li[LI_SINCE] = 0;
    return LOOK_NONE;
}

/* The routine look's condition estimate at any (t, y, yp) and step h (monitor_rcond): what Python's
 * monitor asks first at the looks it makes during a native run (its minimum search between looks
 * evaluates it along an interpolant), before its own LU and SVD where the estimate does not clear the
 * look (phc.simulation.monitor.SingularityMonitor.rcond). */
double phc_ida_rcond(struct phc_ida *w, double t, const double *y, const double *yp, double h)
{
    return monitor_rcond(w->n, w->njac, w->jacobian, w->p, w->jrows, w->jcols, NULL, w->mjbuf, w->mon, w->monpiv,
                         w->monv, t, y, yp, h);
}

/* Up to `budget` of IDA's steps toward t_out[nout - 1]. `k[0]`: the next output index (advanced as the
 * steps pass output times; ys and yps are nout x n). Step i of the call: its end time and size in
 * hist[2 i], hist[2 i + 1]. After the call: steps[0] the steps taken, cur[0] IDA's time, y and yp its
 * state there (n each). h_ref[0], the recent largest step, is max(h, 0.999 h_ref) after each step h
 * (phc.simulation.ida._StepHook's, step by step: the same whatever the chunks). With the routine look on (phc_ida_watch), a look after a step that Python's monitor
 * must make ends the call after that step (PHC_LOOK, li[LI_FLAG] says why), as does a full record of
 * looks (PHC_BUDGET). Returns PHC_DONE (the last output written), PHC_BUDGET (the budget used), PHC_LOOK, or
 * IDA's negative flag. */
int64_t phc_ida_advance(struct phc_ida *w, const double *t_out, int64_t nout, int64_t *k, int64_t budget,
                        double *ys, double *yps, double *hist, int64_t *steps, double *cur, double *y, double *yp,
                        double *h_ref)
{
    const int64_t n = w->n;
    int64_t taken = 0, result = PHC_BUDGET;
    phc_real tret = 0.0, hlast = 0.0;
    double *tmp = N_VGetArrayPointer(w->tmp), *tmp2 = N_VGetArrayPointer(w->tmp2);
    if (w->li != NULL) {
        w->li[LI_LOOKS] = 0;
        w->li[LI_FLAG] = LOOK_NONE;
    }
    while (taken < budget && k[0] < nout) {
        /* toward the next output time: IDA's first step is estimated from it, as in IDA_NORMAL mode */
        int flag = IDASolve(w->mem, t_out[k[0]], &tret, w->yy, w->yp, IDA_ONE_STEP);
        if (flag < 0) {
            result = flag;
            break;
        }
        IDAGetLastStep(w->mem, &hlast);
        hist[2 * taken] = tret;
        hist[2 * taken + 1] = hlast;
        ++taken;
        h_ref[0] = 0.999 * h_ref[0] > hlast ? 0.999 * h_ref[0] : hlast;  /* Python's max(h, 0.999 h_ref) */
        while (k[0] < nout && t_out[k[0]] <= tret) {
            /* the output times this step passed: IDA's interpolating polynomial (exact at tret) */
            double *row = ys + k[0] * n, *rowp = yps + k[0] * n;
            if (t_out[k[0]] == tret) {
                memcpy(row, N_VGetArrayPointer(w->yy), (size_t)n * sizeof(double));
                memcpy(rowp, N_VGetArrayPointer(w->yp), (size_t)n * sizeof(double));
            } else {
                /* IDA_NORMAL mode interpolates with IDAGetSolution, which no installed header declares (a
                 * private function): IDAGetDky, IDA's public interpolation, is the same polynomial summed
                 * in another order (the outputs agree to rounding: 2e-21 on the pendulum's multiplier) */
                IDAGetDky(w->mem, t_out[k[0]], 0, w->tmp);
                IDAGetDky(w->mem, t_out[k[0]], 1, w->tmp2);
                memcpy(row, tmp, (size_t)n * sizeof(double));
                memcpy(rowp, tmp2, (size_t)n * sizeof(double));
            }
            k[0] += 1;
        }
        if (w->li != NULL && ++w->li[LI_SINCE] >= w->li[LI_CADENCE]) {
            const int why = routine_look(w, tret, hlast, w->li[LI_STEPS] + taken);
            if (why != LOOK_NONE) {
                w->li[LI_FLAG] = why;
                result = PHC_LOOK;
                break;
            }
            if (w->li[LI_LOOKS] >= w->li[LI_CAPACITY])
                break;
        }
    }
    if (k[0] >= nout && result == PHC_BUDGET)
        result = PHC_DONE;
    steps[0] = taken;
    cur[0] = tret;
    memcpy(y, N_VGetArrayPointer(w->yy), (size_t)n * sizeof(double));
    memcpy(yp, N_VGetArrayPointer(w->yp), (size_t)n * sizeof(double));
    return result;
}

/* counts[0..5]: residual evaluations, Jacobian evaluations, non-finite evaluations, the latest evaluation
 * non-finite (0/1), IDA's steps, its error-test failures; reals[0..2]: t_failed, cj, IDA's current step;
 * the latest failed point into y_failed, yp_failed (n each). */
void phc_ida_stats(const struct phc_ida *w, int64_t *counts, double *reals, double *y_failed, double *yp_failed)
{
    long int nst = 0, netf = 0;
    phc_real hcur = 0.0;
    IDAGetNumSteps(w->mem, &nst);
    IDAGetNumErrTestFails(w->mem, &netf);
    IDAGetCurrentStep(w->mem, &hcur);
    counts[0] = w->nres;
    counts[1] = w->njacs;
    counts[2] = w->failures;
    counts[3] = w->failed_last;
    counts[4] = nst;
    counts[5] = netf;
    reals[0] = w->t_failed;
    reals[1] = w->cj;
    reals[2] = hcur;
    memcpy(y_failed, w->y_failed, (size_t)w->n * sizeof(double));
    memcpy(yp_failed, w->yp_failed, (size_t)w->n * sizeof(double));
}

/* IDA's latest error message ("" if none) */
const char *phc_ida_message(const struct phc_ida *w)
{
    return w->message;
}

/* [ABI, SUNDIALS' major version, minor version, sizeof(sunindextype), LI_N, LF_N, PHC_LOOK, LOOK_NOT_CLEAR,
 * LOOK_MINIMUM, LOOK_CRAWL] */
void phc_ida_version(int64_t *out)
{
    out[0] = PHC_IDA_ABI;
    out[1] = SUNDIALS_VERSION_MAJOR;
    out[2] = SUNDIALS_VERSION_MINOR;
    out[3] = (int64_t)sizeof(sunindextype);
    out[4] = LI_N;
    out[5] = LF_N;
    out[6] = PHC_LOOK;
    out[7] = LOOK_NOT_CLEAR;
    out[8] = LOOK_MINIMUM;
    out[9] = LOOK_CRAWL;
}
