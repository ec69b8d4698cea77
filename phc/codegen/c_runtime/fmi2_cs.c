/* The FMI 2.0 co-simulation functions of an FMU exported by phc (`phc export MODEL --fmu OUT.fmu`).
 *
 * Part of phc (a compiler for port-Hamiltonian models), shipped with it
 * (phc/codegen/c_runtime/fmi2_cs.c) and copied into every exported FMU's sources/. Not compiled
 * alone: the FMU's generated fmu.c includes steps.c (the implicit midpoint rule's step loop),
 * defines the model's constants (N, NJAC, NEND, NP, NOUT, NPRED, NVR, ENERGY_INDEX, HAS_WEIGHTS,
 * HAS_COLSCALE, GUID, MODEL, T0, STEP, SIZES, P_EXPORTED, Y0, YP0, WEIGHTS, COLSCALE, CONSTANTS,
 * JROWS, JCOLS, END_ROWS, EMASK, ALGMASK, VARIABLES, derived_parameters) and then includes this
 * file, which turns them into the FMI functions over the model's compiled functions (model.c).
 *
 * An instance is one allocation through the importer's allocateMemory: the step loop's state
 * (struct phc_steps of steps.c) over the instance's arrays, the parameters (the inputs among
 * them), the time and the energy at the start. fmi2DoStep(t, H) sets the step loop's output grid
 * to [t, t + H] and runs phc_steps_chunk, which splits it into ceil(H / STEP) equal steps (one when
 * STEP is 0) exactly as `phc simulate` splits an output interval. The file has no mutable static
 * data: instances may run in parallel threads.
 */

/* ---- FMI 2.0 types, as the standard's fmi2TypesPlatform.h and fmi2FunctionTypes.h define them -- */

typedef void *fmi2Component;
typedef void *fmi2ComponentEnvironment;
typedef void *fmi2FMUstate;
typedef unsigned int fmi2ValueReference;
typedef double fmi2Real;
typedef int fmi2Integer;
typedef int fmi2Boolean;
typedef char fmi2Char;
typedef const fmi2Char *fmi2String;
typedef char fmi2Byte;
#define fmi2True 1
#define fmi2False 0

typedef enum { fmi2OK, fmi2Warning, fmi2Discard, fmi2Error, fmi2Fatal, fmi2Pending } fmi2Status;
typedef enum { fmi2ModelExchange, fmi2CoSimulation } fmi2Type;
typedef enum { fmi2DoStepStatus, fmi2PendingStatus, fmi2LastSuccessfulTime, fmi2Terminated } fmi2StatusKind;

typedef void (*fmi2CallbackLogger)(fmi2ComponentEnvironment, fmi2String, fmi2Status, fmi2String, fmi2String, ...);
typedef void *(*fmi2CallbackAllocateMemory)(size_t, size_t);
typedef void (*fmi2CallbackFreeMemory)(void *);
typedef void (*fmi2StepFinished)(fmi2ComponentEnvironment, fmi2Status);

typedef struct {
    fmi2CallbackLogger logger;
    fmi2CallbackAllocateMemory allocateMemory;
    fmi2CallbackFreeMemory freeMemory;
    fmi2StepFinished stepFinished;
    fmi2ComponentEnvironment componentEnvironment;
} fmi2CallbackFunctions;

#define FMI2_EXPORT __attribute__((visibility("default")))

/* ---- the model's functions (model.c) ------------------------------------------------------- */

void phc_residual(double t, const double *y, const double *yp, const double *p, double *out);
void phc_jacobian(double t, const double *y, const double *yp, const double *p, double cj, double *out);
void phc_invariants(double t, const double *y, const double *p, double *out);
double phc_hamiltonian(double t, const double *y, const double *p);
double phc_energy_scale(double t, const double *y, const double *p);
void phc_powers(double t, const double *y, const double *yp, const double *p, double *out);
void phc_outputs(double t, const double *y, const double *yp, const double *p, double *out);
void phc_sizes(long long *out);

/* ---- an instance ------------------------------------------------------------------------------ */

#define MAX1(k) ((k) > 0 ? (k) : 1)

enum phase { INSTANTIATED, INITIALIZATION, STEPPING, TERMINATED, BROKEN };

typedef struct {
    fmi2CallbackFunctions cb;
    char *name;
    int phase, logging, fresh;     /* fresh: outs[] is up to date */
    double t, h0;                  /* time; the energy H at the start */
    double p[MAX1(NP)];            /* parameters (the inputs are parameters too) */
    double outs[MAX1(NOUT)];
    double yp[N];                  /* the rates at t: the last step's difference quotient */
    /* the step loop's state and scratch (struct phc_steps of steps.c) */
    double t_out[2], ys[2 * N], yps[2 * N];
    double y[N], mid[N], mid_slope[N], y_prev[N], y_new[N];
    double pt[NPRED], pm[NPRED * N];
    double fst[F_NF];
    int64_t ist[I_NI + 2];
    double lu[2 * N * N];
    int64_t piv[2 * N], perm[2 * N];
    double eq[4 * N], matf[6];
    double xs[N], d[N], r[N], guess[N], yp_scratch[N], g[MAX1(NEND)];
    double jbuf[NJAC], ebuf[NJAC];
    double mon[N * N], monv[3 * N];
    int64_t monpiv[N];
    double hist_t[6], hist_v[6 * N], sub[3 * N];   /* the other methods' (the FMU runs the midpoint rule) */
    double stage_start[N], y1in[N], y_half[N], y_best[N], y_sec[N];
    struct phc_steps run;
} Instance;

/* A message to the importer's logger (errors always, the rest when logging is on). The text is
 * formatted here; it holds no `%`, so a logger that formats it again prints it unchanged. */
static void say(const Instance *inst, const fmi2CallbackFunctions *cb, const char *name, fmi2Status status,
                const char *fmt, ...)
{
    char text[600];
    va_list args;
    if (cb == NULL || cb->logger == NULL)
        return;
    if (status < fmi2Error && inst != NULL && !inst->logging)
        return;
    va_start(args, fmt);
    vsnprintf(text, sizeof text, fmt, args);
    va_end(args);
    for (char *c = text; *c; ++c)
        if (*c == '%')
            *c = '?';
    cb->logger(cb->componentEnvironment, name ? name : MODEL, status,
               status >= fmi2Error ? "logStatusError" : "logStatusWarning", text);
}

#define FMU_ERROR(inst, ...) (say((inst), &(inst)->cb, (inst)->name, fmi2Error, __VA_ARGS__), fmi2Error)

/* The step loop's struct over the instance's arrays (steps.c reads and writes only these). */
static void bind(Instance *inst)
{
    struct phc_steps *w = &inst->run;
    w->n = N;
    w->njac = NJAC;
    w->nend = NEND;
    w->nout = 2;
    w->npred = NPRED;
    w->residual = phc_residual;
    w->jacobian = phc_jacobian;
    w->invariants = phc_invariants;
    w->p = inst->p;
    w->jrows = JROWS;
    w->jcols = JCOLS;
    w->end_rows = END_ROWS;
    w->emask = EMASK;
    w->algmask = ALGMASK;
    w->weights = HAS_WEIGHTS ? WEIGHTS : NULL;
    w->colscale = HAS_COLSCALE ? COLSCALE : NULL;
    w->c = CONSTANTS;
    w->t_out = inst->t_out;
    w->ys = inst->ys;
    w->yps = inst->yps;
    w->y = inst->y;
    w->mid = inst->mid;
    w->mid_slope = inst->mid_slope;
    w->y_prev = inst->y_prev;
    w->y_new = inst->y_new;
    w->pt = inst->pt;
    w->pm = inst->pm;
    w->fst = inst->fst;
    w->ist = inst->ist;
    w->lu = inst->lu;
    w->piv = inst->piv;
    w->perm = inst->perm;
    w->eq = inst->eq;
    w->matf = inst->matf;
    w->xs = inst->xs;
    w->d = inst->d;
    w->r = inst->r;
    w->guess = inst->guess;
    w->yp = inst->yp_scratch;
    w->g = inst->g;
    w->jbuf = inst->jbuf;
    w->ebuf = inst->ebuf;
    w->mon = inst->mon;
    w->monpiv = inst->monpiv;
    w->monv = inst->monv;
    w->hamiltonian = phc_hamiltonian;
    w->energy_scale = phc_energy_scale;
    w->powers = phc_powers;
    w->hist_t = inst->hist_t;
    w->hist_v = inst->hist_v;
    w->sub = inst->sub;
    w->start = inst->stage_start;
    w->y1in = inst->y1in;
    w->y_half = inst->y_half;
    w->y_best = inst->y_best;
    w->y_sec = inst->y_sec;
    w->events = NULL; /* no switching functions watched (a model with events is not exported) */
    w->nwatch = 0;
    w->nev = 0;
}

/* The start of a run: the exported consistent state and the step loop's state as
 * phc.simulation.compiled_steps.integrate sets it up (no midpoints yet, no Newton matrix). The
 * singularity monitor is off: phc's monitor is Python; a step whose Newton iteration fails is an
 * error of fmi2DoStep. */
static void start(Instance *inst)
{
    memcpy(inst->y, Y0, sizeof inst->y);
    memcpy(inst->mid_slope, YP0, sizeof inst->mid_slope);
    memcpy(inst->yp, YP0, sizeof inst->yp);
    memset(inst->mid, 0, sizeof inst->mid);
    memset(inst->y_prev, 0, sizeof inst->y_prev);
    memset(inst->y_new, 0, sizeof inst->y_new);
    memset(inst->pt, 0, sizeof inst->pt);
    memset(inst->pm, 0, sizeof inst->pm);
    memset(inst->fst, 0, sizeof inst->fst);
    memset(inst->ist, 0, sizeof inst->ist);
    memset(inst->lu, 0, sizeof inst->lu);
    memset(inst->piv, 0, sizeof inst->piv);
    memset(inst->matf, 0, sizeof inst->matf);
    for (int i = 0; i < 4 * N; ++i)
        inst->eq[i] = 1.0;
    inst->ist[I_K] = 1;
    inst->ist[I_LAST_LOOK] = -(int64_t)CONSTANTS[C_EVERY];
    inst->ist[I_MAX_STEPS] = INT64_MAX;
    inst->ist[I_MONITOR] = 0;
    inst->ist[I_METHOD] = 0; /* the implicit midpoint rule */
    inst->ist[I_NEND] = NEND;
    inst->ist[I_E] = ENERGY_INDEX;
    inst->fst[F_STEP] = STEP;
    inst->fst[F_H_PREV] = 1.0;
    inst->t = T0;
    inst->fresh = 0;
    bind(inst);
}

static void refresh(Instance *inst)
{
    if (!inst->fresh) {
        if (NOUT > 0)
            phc_outputs(inst->t, inst->y, inst->yp, inst->p, inst->outs);
        inst->fresh = 1;
    }
}

static double value_of(Instance *inst, const struct fmu_variable *v)
{
    switch (v->kind) {
    case K_VARIABLE:
        return inst->y[v->index];
    case K_OUTPUT:
        refresh(inst);
        return inst->outs[v->index];
    case K_ENERGY:
        return phc_hamiltonian(inst->t, inst->y, inst->p);
    case K_BALANCE:
        return phc_hamiltonian(inst->t, inst->y, inst->p) - inst->h0 + inst->y[ENERGY_INDEX];
    default: /* K_PARAMETER, K_CONSTANT, K_INPUT */
        return inst->p[v->index];
    }
}

/* A tunable parameter changed between steps: the derived parameters follow; the stored energy
 * jumps with the parameter (not with the state), and that jump is booked into the start energy,
 * so that energy.balance_error measures the method alone; the Newton matrix is factorized anew
 * at the next step. */
static void tune(Instance *inst, int index, double value)
{
    const double before = phc_hamiltonian(inst->t, inst->y, inst->p);
    inst->p[index] = value;
    derived_parameters(inst->p);
    inst->h0 += phc_hamiltonian(inst->t, inst->y, inst->p) - before;
    inst->matf[2] = 0.0;
    inst->matf[5] = 0.0;
}

/* ---- the FMI 2.0 functions ------------------------------------------------------------------- */

FMI2_EXPORT const char *fmi2GetTypesPlatform(void) { return "default"; }
FMI2_EXPORT const char *fmi2GetVersion(void) { return "2.0"; }

FMI2_EXPORT fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                                           const fmi2String categories[])
{
    (void)nCategories;
    (void)categories;
    if (c == NULL)
        return fmi2Error;
    ((Instance *)c)->logging = loggingOn != fmi2False;
    return fmi2OK;
}

FMI2_EXPORT fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                                          fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                                          fmi2Boolean visible, fmi2Boolean loggingOn)
{
    (void)fmuResourceLocation;
    (void)visible;
    if (functions == NULL || functions->allocateMemory == NULL || functions->freeMemory == NULL)
        return NULL;
    if (fmuType != fmi2CoSimulation) {
        say(NULL, functions, instanceName, fmi2Error, "%s is a co-simulation FMU: model exchange is not offered "
            "(a port-Hamiltonian DAE with constraints is not an ODE the importer could integrate)", MODEL);
        return NULL;
    }
    if (fmuGUID == NULL || strcmp(fmuGUID, GUID) != 0) {
        say(NULL, functions, instanceName, fmi2Error, "the GUID given does not match this binary's (%s): "
            "the modelDescription.xml is from another export", GUID);
        return NULL;
    }
    long long sizes[8];
    phc_sizes(sizes);
    for (int k = 0; k < 8; ++k)
        if (SIZES[k] >= 0 && sizes[k] != SIZES[k]) {
            say(NULL, functions, instanceName, fmi2Error, "model.c was generated for another model (size "
                "entry %d is %lld, expected %lld): export again", k, sizes[k], SIZES[k]);
            return NULL;
        }
    Instance *inst = (Instance *)functions->allocateMemory(1, sizeof(Instance));
    if (inst == NULL)
        return NULL;
    memset(inst, 0, sizeof(Instance));
    inst->cb = *functions;
    const char *name = instanceName ? instanceName : MODEL;
    inst->name = (char *)functions->allocateMemory(strlen(name) + 1, 1);
    if (inst->name == NULL) {
        functions->freeMemory(inst);
        return NULL;
    }
    memcpy(inst->name, name, strlen(name) + 1);
    inst->logging = loggingOn != fmi2False;
    memcpy(inst->p, P_EXPORTED, sizeof(double) * NP);
    start(inst);
    inst->h0 = phc_hamiltonian(inst->t, inst->y, inst->p);
    inst->phase = INSTANTIATED;
    return inst;
}

FMI2_EXPORT void fmi2FreeInstance(fmi2Component c)
{
    Instance *inst = (Instance *)c;
    if (inst == NULL)
        return;
    fmi2CallbackFreeMemory release = inst->cb.freeMemory;
    release(inst->name);
    release(inst);
}

FMI2_EXPORT fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                                           fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    Instance *inst = (Instance *)c;
    (void)toleranceDefined; /* a fixed-step method: its accuracy is set by the step (STEP) */
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (inst == NULL)
        return fmi2Error;
    if (inst->phase != INSTANTIATED)
        return FMU_ERROR(inst, "fmi2SetupExperiment is allowed only after fmi2Instantiate");
    if (startTime != T0)
        return FMU_ERROR(inst, "this FMU starts at t = %.17g, where phc computed its consistent initial state (the "
                    "model's simulation start), not at t = %.17g", T0, startTime);
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    Instance *inst = (Instance *)c;
    if (inst == NULL)
        return fmi2Error;
    if (inst->phase != INSTANTIATED)
        return FMU_ERROR(inst, "fmi2EnterInitializationMode is allowed only after fmi2Instantiate");
    inst->phase = INITIALIZATION;
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    Instance *inst = (Instance *)c;
    if (inst == NULL)
        return fmi2Error;
    if (inst->phase != INITIALIZATION)
        return FMU_ERROR(inst, "fmi2ExitInitializationMode is allowed only in initialization mode");
    int changed = 0;
    for (int k = 0; k < NVR; ++k) {
        const struct fmu_variable *v = &VARIABLES[k];
        if (v->kind != K_PARAMETER || inst->p[v->index] == P_EXPORTED[v->index])
            continue;
        changed = 1;
        if (v->fixes_start) {
            inst->phase = BROKEN;
            return FMU_ERROR(inst, "parameter `%s` = %.17g: the consistent initial state depends on it and phc "
                        "computed it at export, with %s = %.17g; export the FMU again with the value (phc export MODEL "
                        "--fmu OUT.fmu --param %s=%.17g)", v->name, inst->p[v->index], v->name,
                        P_EXPORTED[v->index], v->name, inst->p[v->index]);
        }
    }
    if (changed)
        derived_parameters(inst->p);
    for (int i = 0; i < NP; ++i)
        if (!isfinite(inst->p[i])) {
            inst->phase = BROKEN;
            return FMU_ERROR(inst, "parameter %d is not finite with the values set", i);
        }
    start(inst);
    inst->h0 = phc_hamiltonian(inst->t, inst->y, inst->p);
    inst->phase = STEPPING;
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2Terminate(fmi2Component c)
{
    Instance *inst = (Instance *)c;
    if (inst == NULL)
        return fmi2Error;
    inst->phase = TERMINATED;
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2Reset(fmi2Component c)
{
    Instance *inst = (Instance *)c;
    if (inst == NULL)
        return fmi2Error;
    memcpy(inst->p, P_EXPORTED, sizeof(double) * NP);
    start(inst);
    inst->h0 = phc_hamiltonian(inst->t, inst->y, inst->p);
    inst->phase = INSTANTIATED;
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    Instance *inst = (Instance *)c;
    if (inst == NULL)
        return fmi2Error;
    for (size_t k = 0; k < nvr; ++k) {
        if (vr[k] >= NVR)
            return FMU_ERROR(inst, "no variable has the value reference %u", vr[k]);
        value[k] = value_of(inst, &VARIABLES[vr[k]]);
    }
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[])
{
    Instance *inst = (Instance *)c;
    if (inst == NULL)
        return fmi2Error;
    for (size_t k = 0; k < nvr; ++k) {
        if (vr[k] >= NVR)
            return FMU_ERROR(inst, "no variable has the value reference %u", vr[k]);
        const struct fmu_variable *v = &VARIABLES[vr[k]];
        if (!isfinite(value[k]))
            return FMU_ERROR(inst, "`%s` must be set to a finite number", v->name);
        if (v->kind != K_PARAMETER && v->kind != K_INPUT)
            return FMU_ERROR(inst, "`%s` cannot be set (it is computed by the model)", v->name);
        if (inst->phase == TERMINATED || inst->phase == BROKEN)
            return FMU_ERROR(inst, "`%s` cannot be set after the run ended", v->name);
        if (v->kind == K_PARAMETER && inst->phase == STEPPING) {
            if (v->fixes_start)
                return FMU_ERROR(inst, "parameter `%s` is fixed during the run (the consistent state depends on "
                                 "it): set it before fmi2ExitInitializationMode", v->name);
            tune(inst, v->index, value[k]);
        } else {
            inst->p[v->index] = value[k];
        }
        inst->fresh = 0;
    }
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                                  fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    Instance *inst = (Instance *)c;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (inst == NULL)
        return fmi2Error;
    if (inst->phase != STEPPING)
        return FMU_ERROR(inst, "fmi2DoStep is allowed only after fmi2ExitInitializationMode (and before an error)");
    const double t = currentCommunicationPoint, H = communicationStepSize;
    if (!(H > 0.0) || !isfinite(t + H))
        return FMU_ERROR(inst, "the communication step must be a positive finite number, got %.17g", H);
    if (fabs(t - inst->t) > 1e-9 * (fabs(inst->t) + H))
        return FMU_ERROR(inst, "the communication point t = %.17g is not the FMU's time %.17g (no rollback: "
                    "canGetAndSetFMUstate is false)", t, inst->t);
    inst->t_out[0] = t;
    inst->t_out[1] = t + H;
    inst->ist[I_K] = 1;
    inst->ist[I_J] = 0;
    phc_steps_chunk(&inst->run, INT64_MAX);
    if (inst->ist[I_STATUS] != ST_DONE) {
        const double ts = inst->fst[F_T], h = inst->fst[F_H];
        const int64_t code = inst->ist[I_CODE];
        inst->phase = BROKEN;
        inst->t = ts;
        inst->fresh = 0;
        if (code == SINGULAR)
            return FMU_ERROR(inst, "singular Newton matrix in the step from t = %.17g (h = %.6g): the model may be "
                        "at a singular configuration", ts, h);
        if (code == EVAL)
            return FMU_ERROR(inst, "the model cannot be evaluated in the step from t = %.17g (h = %.6g): a value "
                        "outside an expression's domain", ts, h);
        return FMU_ERROR(inst, "Newton did not converge in the step from t = %.17g (h = %.6g); export with a smaller "
                    "step (phc export --step)", ts, h);
    }
    memcpy(inst->yp, inst->yps + N, sizeof inst->yp);
    inst->t = t + H;
    inst->fresh = 0;
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2CancelStep(fmi2Component c)
{
    return c == NULL ? fmi2Error : FMU_ERROR((Instance *)c, "fmi2CancelStep: fmi2DoStep is synchronous here");
}

/* ---- what this FMU does not offer ------------------------------------------------------------ */

static fmi2Status none(fmi2Component c, size_t nvr, const char *what)
{
    if (c == NULL)
        return fmi2Error;
    return nvr == 0 ? fmi2OK : FMU_ERROR((Instance *)c, "this FMU has no %s variables", what);
}

FMI2_EXPORT fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[])
{
    (void)vr;
    (void)value;
    return none(c, nvr, "Integer");
}

FMI2_EXPORT fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[])
{
    (void)vr;
    (void)value;
    return none(c, nvr, "Boolean");
}

FMI2_EXPORT fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[])
{
    (void)vr;
    (void)value;
    return none(c, nvr, "String");
}

FMI2_EXPORT fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                      const fmi2Integer value[])
{
    (void)vr;
    (void)value;
    return none(c, nvr, "Integer");
}

FMI2_EXPORT fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                      const fmi2Boolean value[])
{
    (void)vr;
    (void)value;
    return none(c, nvr, "Boolean");
}

FMI2_EXPORT fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                     const fmi2String value[])
{
    (void)vr;
    (void)value;
    return none(c, nvr, "String");
}

static fmi2Status not_offered(fmi2Component c, const char *what)
{
    return c == NULL ? fmi2Error : FMU_ERROR((Instance *)c, "%s is not offered by this FMU", what);
}

FMI2_EXPORT fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state)
{
    (void)state;
    return not_offered(c, "fmi2GetFMUstate");
}

FMI2_EXPORT fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state)
{
    (void)state;
    return not_offered(c, "fmi2SetFMUstate");
}

FMI2_EXPORT fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state)
{
    (void)state;
    return not_offered(c, "fmi2FreeFMUstate");
}

FMI2_EXPORT fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size)
{
    (void)state;
    (void)size;
    return not_offered(c, "fmi2SerializedFMUstateSize");
}

FMI2_EXPORT fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[], size_t size)
{
    (void)state;
    (void)bytes;
    (void)size;
    return not_offered(c, "fmi2SerializeFMUstate");
}

FMI2_EXPORT fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size,
                                               fmi2FMUstate *state)
{
    (void)bytes;
    (void)size;
    (void)state;
    return not_offered(c, "fmi2DeSerializeFMUstate");
}

FMI2_EXPORT fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown[],
                                                    size_t nUnknown, const fmi2ValueReference vKnown[],
                                                    size_t nKnown, const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    (void)vUnknown;
    (void)nUnknown;
    (void)vKnown;
    (void)nKnown;
    (void)dvKnown;
    (void)dvUnknown;
    return not_offered(c, "fmi2GetDirectionalDerivative");
}

FMI2_EXPORT fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                                   const fmi2Integer order[], const fmi2Real value[])
{
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return not_offered(c, "fmi2SetRealInputDerivatives (the inputs are held over a step)");
}

FMI2_EXPORT fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                                    const fmi2Integer order[], fmi2Real value[])
{
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return not_offered(c, "fmi2GetRealOutputDerivatives");
}

FMI2_EXPORT fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
{
    (void)s;
    (void)value;
    return c == NULL ? fmi2Error : fmi2Discard;
}

FMI2_EXPORT fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value)
{
    if (c == NULL)
        return fmi2Error;
    if (s != fmi2LastSuccessfulTime)
        return fmi2Discard;
    *value = ((Instance *)c)->t;
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value)
{
    (void)s;
    (void)value;
    return c == NULL ? fmi2Error : fmi2Discard;
}

FMI2_EXPORT fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value)
{
    if (c == NULL)
        return fmi2Error;
    if (s != fmi2Terminated)
        return fmi2Discard;
    *value = fmi2False;
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value)
{
    (void)s;
    (void)value;
    return c == NULL ? fmi2Error : fmi2Discard;
}
