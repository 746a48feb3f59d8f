/*
 * fmi_layer.c: FMI-version-independent layer, Co-Simulation and Model Exchange (see
 * fmi_layer.h).
 *
 * Habits borrowed from modelica/Reference-FMUs: every entry point first
 * checks that the call is allowed in the current state, null pointers and
 * value references are validated before anything is changed, values that are
 * set are applied all-or-nothing, and outputs are computed lazily behind a
 * dirty flag.
 *
 * Error policy: a rejected call (illegal call sequence, bad value reference,
 * non-finite or out-of-range value) returns FL_ERROR, logs why and leaves the
 * instance unchanged.  A failed computation (initialisation or doStep)
 * returns FL_ERROR, keeps the last good state and outputs and puts the
 * instance into the Error state, from which fmiSetFMUState, fmiReset, the
 * getters and fmiFreeInstance remain possible (as the FMI standard says).
 */
#include <ctype.h>
#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi_layer.h"

#define FL_MSG_SIZE 1024

/* ------------------------------------------------------------------------ */
/* logging                                                                  */
/* ------------------------------------------------------------------------ */

static void vlog(FlInstance *inst, FlStatus status, const char *fmt, va_list ap) {
    char buf[FL_MSG_SIZE];
    const char *category;
    if (!inst || !inst->log_adapter || !inst->importer_logger) return;
    if (status == FL_OK && !(inst->logging_on && inst->log_events)) return;
    vsnprintf(buf, sizeof(buf), fmt, ap);
    switch (status) {
    case FL_OK: category = FL_CAT_EVENTS; break;
    case FL_WARNING: category = FL_CAT_WARNING; break;
    case FL_DISCARD: category = "logStatusDiscard"; break;
    case FL_ERROR: category = FL_CAT_ERROR; break;
    default: category = "logStatusFatal"; break;
    }
    inst->log_adapter(inst, status, category, buf);
}

WMR_INTERNAL
void fl_log(FlInstance *inst, FlStatus status, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vlog(inst, status, fmt, ap);
    va_end(ap);
}

WMR_INTERNAL
void fl_log_no_instance(const char *instance_name, FlLogAdapter adapter,
                        void (*importer_logger)(void), void *importer_env,
                        FlStatus status, const char *fmt, ...) {
    FlInstance tmp;
    va_list ap;
    memset(&tmp, 0, sizeof(tmp));
    tmp.name = (char *)(instance_name ? instance_name : "?");
    tmp.log_adapter = adapter;
    tmp.importer_logger = importer_logger;
    tmp.importer_env = importer_env;
    tmp.logging_on = 1;
    tmp.log_events = 1;
    va_start(ap, fmt);
    vlog(&tmp, status, fmt, ap);
    va_end(ap);
}

/* Record a status in the instance and return it. */
static FlStatus ret(FlInstance *inst, FlStatus status) {
    if (inst && status > inst->worst_status) inst->worst_status = status;
    return status;
}

/* A computation failed: last good values are kept, the instance is in Error. */
static FlStatus fail(FlInstance *inst) {
    inst->d.mode = FL_ERROR_STATE;
    return ret(inst, FL_ERROR);
}

WMR_INTERNAL
const char *fl_mode_name(int mode) {
    switch (mode) {
    case FL_INSTANTIATED: return "Instantiated";
    case FL_INITIALIZATION_MODE: return "InitializationMode";
    case FL_STEP_MODE: return "StepMode";
    case FL_TERMINATED: return "Terminated";
    case FL_ERROR_STATE: return "Error";
    case FL_EVENT_MODE: return "EventMode";
    case FL_CONTINUOUS_TIME_MODE: return "ContinuousTimeMode";
    }
    return "Unknown";
}

static void mask_names(int mask, char *buf, size_t size) {
    static const int modes[] = {FL_INSTANTIATED, FL_INITIALIZATION_MODE, FL_STEP_MODE,
                                FL_EVENT_MODE, FL_CONTINUOUS_TIME_MODE, FL_TERMINATED,
                                FL_ERROR_STATE};
    size_t i, len = 0;
    int first = 1;
    buf[0] = '\0';
    for (i = 0; i < sizeof(modes) / sizeof(modes[0]); i++) {
        if (mask & modes[i]) {
            int n = snprintf(buf + len, size - len, "%s%s", first ? "" : " or ",
                             fl_mode_name(modes[i]));
            if (n < 0 || (size_t)n >= size - len) return;
            len += (size_t)n;
            first = 0;
        }
    }
}

WMR_INTERNAL
int fl_check_state(const char *fn, FlInstance *inst, int mask) {
    char expected[192];
    if (!inst) return 0;
    if (inst->d.mode & mask) return 1;
    mask_names(mask, expected, sizeof(expected));
    fl_log(inst, FL_ERROR, "%s: expected state %s, was %s", fn, expected,
           fl_mode_name(inst->d.mode));
    ret(inst, FL_ERROR);
    return 0;
}

WMR_INTERNAL
FlStatus fl_unsupported(const char *fn, FlInstance *inst, const char *why) {
    if (!inst) return FL_ERROR;
    fl_log(inst, FL_ERROR, "%s: not supported: %s", fn, why);
    return ret(inst, FL_ERROR);
}

WMR_INTERNAL
FlStatus fl_no_variables_of_type(const char *fn, FlInstance *inst, int mask,
                                 const unsigned int vr[], size_t nvr, const char *type_name) {
    if (!fl_check_state(fn, inst, mask)) return FL_ERROR;
    if (nvr == 0) return FL_OK;
    if (!vr) {
        fl_log(inst, FL_ERROR, "%s: valueReferences is NULL", fn);
        return ret(inst, FL_ERROR);
    }
    if (vr[0] < MODEL_NV)
        fl_log(inst, FL_ERROR, "%s: value reference %u (%s) is not of type %s; the model has only Real/Float64 variables",
               fn, vr[0], MODEL_VARIABLES[vr[0]].name, type_name);
    else
        fl_log(inst, FL_ERROR, "%s: value reference %u does not exist; the model has no %s variables",
               fn, vr[0], type_name);
    return ret(inst, FL_ERROR);
}

WMR_INTERNAL
FlStatus fl_set_debug_logging(const char *fn, FlInstance *inst, int logging_on,
                              size_t n_categories, const char *const categories[]) {
    size_t i;
    FlStatus status = FL_OK;
    if (!inst) return FL_ERROR;
    if (n_categories > 0 && !categories) {
        fl_log(inst, FL_ERROR, "%s: categories is NULL but nCategories = %lu", fn,
               (unsigned long)n_categories);
        return ret(inst, FL_ERROR);
    }
    inst->logging_on = logging_on ? 1 : 0;
    if (n_categories == 0) {
        inst->log_events = 1;
        return FL_OK;
    }
    inst->log_events = 0;
    for (i = 0; i < n_categories; i++) {
        const char *c = categories[i];
        if (!c) continue;
        if (!strcmp(c, FL_CAT_EVENTS) || !strcmp(c, FL_CAT_ALL)) {
            inst->log_events = 1;
        } else if (!strcmp(c, FL_CAT_ERROR) || !strcmp(c, FL_CAT_WARNING)) {
            /* errors and warnings are always reported */
        } else {
            fl_log(inst, FL_WARNING, "%s: unknown log category \"%s\" ignored (known: %s, %s, %s, %s)",
                   fn, c, FL_CAT_EVENTS, FL_CAT_WARNING, FL_CAT_ERROR, FL_CAT_ALL);
            status = FL_WARNING;
        }
    }
    return ret(inst, status);
}

/* ------------------------------------------------------------------------ */
/* helpers                                                                  */
/* ------------------------------------------------------------------------ */

static const char *kind_name(ModelVarKind kind) {
    switch (kind) {
    case MODEL_VAR_TIME: return "independent variable";
    case MODEL_VAR_PARAMETER: return "parameter";
    case MODEL_VAR_INPUT: return "input";
    case MODEL_VAR_OUTPUT: return "output";
    case MODEL_VAR_DERIVATIVE: return "state derivative";
    }
    return "variable";
}

static const char *output_name(int index) {
    int v;
    for (v = 0; v < MODEL_NV; v++)
        if (MODEL_VARIABLES[v].kind == MODEL_VAR_OUTPUT && MODEL_VARIABLES[v].index == index)
            return MODEL_VARIABLES[v].name;
    return "?";
}

static int check_table(char *msg, size_t size) {
    int v, n_p = 0, n_u = 0, n_y = 0, n_d = 0;
    if (MODEL_VARIABLES[0].kind != MODEL_VAR_TIME) {
        snprintf(msg, size, "variable table: entry 0 is not time");
        return 0;
    }
    for (v = 1; v < MODEL_NV; v++) {
        const ModelVariable *mv = &MODEL_VARIABLES[v];
        int limit;
        switch (mv->kind) {
        case MODEL_VAR_PARAMETER: limit = MODEL_NP; n_p++; break;
        case MODEL_VAR_INPUT: limit = MODEL_NU; n_u++; break;
        case MODEL_VAR_OUTPUT: limit = MODEL_NY; n_y++; break;
        case MODEL_VAR_DERIVATIVE: limit = MODEL_NX; n_d++; break;
        default:
            snprintf(msg, size, "variable table: entry %d (%s) has an invalid kind", v, mv->name);
            return 0;
        }
        if (mv->index < 0 || mv->index >= limit) {
            snprintf(msg, size, "variable table: entry %d (%s) has index %d out of range", v,
                     mv->name, mv->index);
            return 0;
        }
        if (mv->state >= MODEL_NX || (mv->state >= 0 && mv->kind != MODEL_VAR_OUTPUT)) {
            snprintf(msg, size, "variable table: entry %d (%s) has state %d out of range", v,
                     mv->name, mv->state);
            return 0;
        }
    }
    if (n_d != 0 && n_d != MODEL_NX) {
        snprintf(msg, size, "variable table: %d state derivatives for %d states", n_d, MODEL_NX);
        return 0;
    }
    if (n_p != MODEL_NP || n_u != MODEL_NU || n_y != MODEL_NY) {
        snprintf(msg, size, "variable table: %d parameters, %d inputs, %d outputs; expected %d, %d, %d",
                 n_p, n_u, n_y, MODEL_NP, MODEL_NU, MODEL_NY);
        return 0;
    }
    return 1;
}

/* Start values, time 0, mode Instantiated. */
static void set_start_values(FlInstance *inst) {
    FlData *d = &inst->d;
    double x0[MODEL_NX];
    int v, i, ok;
    memset(d, 0, sizeof(*d)); /* also zeroes padding: serialized states are deterministic */
    d->mode = FL_INSTANTIATED;
    d->time = 0.0;
    d->start_time = 0.0;
    d->stop_time = 0.0;
    d->stop_time_defined = 0;
    for (v = 0; v < MODEL_NV; v++) {
        const ModelVariable *mv = &MODEL_VARIABLES[v];
        if (mv->kind == MODEL_VAR_PARAMETER) d->p[mv->index] = mv->start;
        else if (mv->kind == MODEL_VAR_INPUT) d->u[mv->index] = mv->start;
    }
    for (i = 0; i < inst->n_start_values; i++)
        d->p[MODEL_VARIABLES[inst->start_vr[i]].index] = inst->start_value[i];
    solver_init(&d->solver);
    ok = model_initial_state(d->p, x0) == 0;
    for (i = 0; ok && i < MODEL_NX; i++) ok = isfinite(x0[i]);
    for (i = 0; i < MODEL_NX; i++) d->x[i] = ok ? x0[i] : 0.0;
    d->outputs_dirty = 1;
    d->n_comm_steps = 0;
}

static int find_nonfinite(const double *v, int n) {
    int i;
    for (i = 0; i < n; i++)
        if (!isfinite(v[i])) return i;
    return -1;
}

/* Initial state from p (initialisation mode); logs and returns 0 on failure. */
static int compute_initial_state(const char *fn, FlInstance *inst, double x[MODEL_NX]) {
    int i;
    if (model_initial_state(inst->d.p, x) != 0) {
        fl_log(inst, FL_ERROR, "%s: model_initial_state failed; check the parameters", fn);
        return 0;
    }
    if ((i = find_nonfinite(x, MODEL_NX)) >= 0) {
        fl_log(inst, FL_ERROR, "%s: initial state %d = %g is not a finite number; check the parameters",
               fn, i, x[i]);
        return 0;
    }
    return 1;
}

/* y = g(x, u, p) with checks; logs and returns 0 on failure. */
static int compute_outputs(const char *fn, FlInstance *inst, const double x[MODEL_NX],
                           double y[MODEL_NY]) {
    int i;
#if MODEL_SAMPLED
    double z_next[MODEL_NX];
    if (inst->d.run_over ? model_rest(x, inst->d.u, inst->d.p, y, z_next) != 0
                         : model_outputs(x, inst->d.u, inst->d.p, y) != 0) {
#else
    if (model_outputs(x, inst->d.u, inst->d.p, y) != 0) {
#endif
        fl_log(inst, FL_ERROR, "%s: model_outputs failed at t = %.17g", fn, inst->d.time);
        return 0;
    }
    if ((i = find_nonfinite(y, MODEL_NY)) >= 0) {
        fl_log(inst, FL_ERROR, "%s: output %s = %g is not a finite number at t = %.17g", fn,
               output_name(i), y[i], inst->d.time);
        return 0;
    }
    return 1;
}

static double time_tol(double t) { return FL_TIME_TOL * (fabs(t) > 1.0 ? fabs(t) : 1.0); }

#if MODEL_SAMPLED
/* Sample n is taken at start_time + n * period: a grid, never accumulated, whatever the
 * master's steps. */
static double sample_time(const FlData *d, unsigned long n) {
    return d->start_time + (double)n * model_sample_period(d->p);
}

/* 1 if the next sample is due at the current time: the outputs are then the sample g(z, u)
 * with direct feedthrough; between grid points they hold the last sample. */
static int sample_due(const FlData *d) {
    return sample_time(d, d->n_samples) <= d->time + time_tol(d->time);
}
#endif

/* Re-evaluate the outputs if the time, state, inputs or parameters changed (lazy): they are a
 * function of those alone (for a sampled-data model also of whether the time is on the sample
 * grid), never of which setters were called. */
static int update_outputs(const char *fn, FlInstance *inst) {
    FlData *d = &inst->d;
    double x[MODEL_NX], y[MODEL_NY];
    if (!d->outputs_dirty) return 1;
    if (!(d->mode & (FL_INITIALIZATION_MODE | FL_SIMULATING))) return 1;
    memcpy(x, d->x, sizeof(x));
    if (d->mode == FL_INITIALIZATION_MODE && !compute_initial_state(fn, inst, x)) return 0;
#if MODEL_SAMPLED
    if (d->mode != FL_INITIALIZATION_MODE && !sample_due(d)) {
        memcpy(d->y, d->y_held, sizeof(d->y)); /* between samples: the last one, held */
        d->outputs_dirty = 0;
        return 1;
    }
#endif
    if (!compute_outputs(fn, inst, x, y)) return 0;
    memcpy(d->x, x, sizeof(x));
    memcpy(d->y, y, sizeof(y));
    d->outputs_dirty = 0;
    return 1;
}

/* dx/dt at the current state (in InitializationMode the initial state from p); logs and
 * returns 0 on failure. */
static int compute_derivatives(const char *fn, FlInstance *inst, double dx[]) {
    FlData *d = &inst->d;
    int i;
    if (!update_outputs(fn, inst)) return 0;
    if (model_derivatives(d->x, d->u, d->p, dx) != 0) {
        fl_log(inst, FL_ERROR, "%s: model_derivatives failed at t = %.17g", fn, d->time);
        return 0;
    }
    if ((i = find_nonfinite(dx, MODEL_NX)) >= 0) {
        fl_log(inst, FL_ERROR, "%s: derivative of state %d = %g is not a finite number at t = %.17g",
               fn, i, dx[i], d->time);
        return 0;
    }
    return 1;
}

/* ------------------------------------------------------------------------ */
/* creation and destruction                                                 */
/* ------------------------------------------------------------------------ */

#define FL_START_VALUES "start_values.txt"
#define FL_PATH_SIZE 4096

/* The path of resources/start_values.txt from the resource location the importer gave: FMI 2
 * a file URI ("file:///dir", "file:/dir", "file://localhost/dir"; percent-encoded), FMI 3 a
 * native path.  Returns 0 when there is no usable location (no file is then read). */
static int start_values_path(const char *resources, int is_uri, char *out, size_t size) {
    const char *p = resources;
    size_t n = 0;
    if (!p || !p[0]) return 0;
    if (is_uri) {
        if (strncmp(p, "file://localhost/", 17) == 0) p += 16;
        else if (strncmp(p, "file:///", 8) == 0) p += 7;
        else if (strncmp(p, "file:/", 6) == 0) p += 5;
        else return 0; /* not a local file: nothing to read */
        if (isalpha((unsigned char)p[1]) && p[2] == ':') p++; /* "/C:/..." on Windows */
    }
    for (; *p && n + 1 < size; p++) {
        if (is_uri && p[0] == '%' && isxdigit((unsigned char)p[1]) &&
            isxdigit((unsigned char)p[2])) {
            char hex[3] = {p[1], p[2], 0};
            out[n++] = (char)strtol(hex, NULL, 16);
            p += 2;
        } else {
            out[n++] = *p;
        }
    }
    if (n > 0 && out[n - 1] != '/' && out[n - 1] != '\\' && n + 1 < size) out[n++] = '/';
    if (n + sizeof(FL_START_VALUES) > size) return 0;
    memcpy(out + n, FL_START_VALUES, sizeof(FL_START_VALUES));
    return 1;
}

/* Read resources/start_values.txt, one "name = 0xBITS" a line (the IEEE 754 binary64 bits in
 * hex, then an optional "# comment"): exact, and unlike strtod independent of the master's
 * locale (a comma radix would read "3.5" as 3).  Parameters only, finite and within their
 * bounds.  No file: nothing to apply.  Returns 0 (logged, naming the file, line and variable) on a file it cannot use: an
 * instance that would run other parameters than its package's must not start. */
static int read_start_values(const char *fn, FlInstance *inst, const char *resources,
                             int is_uri) {
    char path[FL_PATH_SIZE], line[512];
    FILE *f;
    int line_no = 0, ok = 1;
    if (!start_values_path(resources, is_uri, path, sizeof(path))) return 1;
    f = fopen(path, "r");
    if (!f) return 1; /* an FMU of no package: its compiled-in start values */
    while (ok && fgets(line, sizeof(line), f)) {
        char *name = line, *eq, *end, *value;
        size_t len;
        int v, found = -1;
        uint64_t bits;
        double x;
        line_no++;
        while (isspace((unsigned char)*name)) name++;
        if (!*name || *name == '#') continue;
        eq = strchr(name, '=');
        if (!eq || !(strchr(line, '\n') || feof(f))) {
            fl_log(inst, FL_ERROR, "%s: %s line %d: not \"name = 0xBITS\" (or longer than "
                   "%d characters)", fn, path, line_no, (int)sizeof(line) - 2);
            ok = 0;
            break;
        }
        for (len = (size_t)(eq - name); len > 0 && isspace((unsigned char)name[len - 1]);) len--;
        for (v = 0; v < MODEL_NV; v++)
            if (strlen(MODEL_VARIABLES[v].name) == len &&
                strncmp(MODEL_VARIABLES[v].name, name, len) == 0) found = v;
        value = eq + 1;
        while (isspace((unsigned char)*value)) value++;
        bits = 0;
        end = value; /* not 0x...: refused below */
        if (value[0] == '0' && (value[1] == 'x' || value[1] == 'X')) {
            errno = 0;
            bits = (uint64_t)strtoull(value, &end, 16);
            if (errno == ERANGE) end = value;
        }
        memcpy(&x, &bits, sizeof(x));
        while (isspace((unsigned char)*end)) end++;
        if (*end == '#') end += strlen(end);
        if (found < 0 || MODEL_VARIABLES[found].kind != MODEL_VAR_PARAMETER) {
            fl_log(inst, FL_ERROR, "%s: %s line %d: %.*s is not a parameter of %s", fn, path,
                   line_no, (int)len, name, MODEL_IDENTIFIER_STR);
            ok = 0;
        } else if (end == value || *end || !isfinite(x) || x < MODEL_VARIABLES[found].min ||
                   x > MODEL_VARIABLES[found].max) {
            fl_log(inst, FL_ERROR, "%s: %s line %d: %s: the value is not the bits (0x...) "
                   "of a finite number within [%g, %g]", fn, path, line_no,
                   MODEL_VARIABLES[found].name, MODEL_VARIABLES[found].min,
                   MODEL_VARIABLES[found].max);
            ok = 0;
        } else if (inst->n_start_values >= MODEL_NV) {
            fl_log(inst, FL_ERROR, "%s: %s: more than %d lines", fn, path, MODEL_NV);
            ok = 0;
        } else {
            inst->start_vr[inst->n_start_values] = (unsigned int)found;
            inst->start_value[inst->n_start_values++] = x;
        }
    }
    fclose(f);
    if (ok && inst->n_start_values > 0)
        fl_log(inst, FL_OK, "%s: %d start values from %s", fn, inst->n_start_values, path);
    return ok;
}

WMR_INTERNAL
FlInstance *fl_instantiate(const char *fn, const char *instance_name, const char *token,
                           int model_exchange, int logging_on, FlLogAdapter adapter,
                           void (*importer_logger)(void), void *importer_env,
                           const char *resources, int resources_is_uri) {
    FlInstance *inst;
    char msg[FL_MSG_SIZE];
    size_t len;

    if (!instance_name || !instance_name[0]) {
        fl_log_no_instance(instance_name, adapter, importer_logger, importer_env, FL_ERROR,
                           "%s: instanceName must be a non-empty string", fn);
        return NULL;
    }
    if (!token || strcmp(token, MODEL_INSTANTIATION_TOKEN) != 0) {
        fl_log_no_instance(instance_name, adapter, importer_logger, importer_env, FL_ERROR,
                           "%s: instantiation token mismatch: expected \"%s\", got \"%s\" "
                           "(the modelDescription.xml does not belong to this binary)",
                           fn, MODEL_INSTANTIATION_TOKEN, token ? token : "(null)");
        return NULL;
    }
    if (model_exchange && (MODEL_NX == 0 || MODEL_SAMPLED)) {
        fl_log_no_instance(instance_name, adapter, importer_logger, importer_env, FL_ERROR,
                           "%s: this model has no continuous states: Model Exchange is not "
                           "provided, instantiate it for Co-Simulation", fn);
        return NULL;
    }
    if (!check_table(msg, sizeof(msg))) {
        fl_log_no_instance(instance_name, adapter, importer_logger, importer_env, FL_ERROR,
                           "%s: %s", fn, msg);
        return NULL;
    }
    inst = (FlInstance *)calloc(1, sizeof(FlInstance));
    len = strlen(instance_name);
    if (inst) inst->name = (char *)malloc(len + 1);
    if (!inst || !inst->name) {
        free(inst);
        fl_log_no_instance(instance_name, adapter, importer_logger, importer_env, FL_ERROR,
                           "%s: out of memory", fn);
        return NULL;
    }
    memcpy(inst->name, instance_name, len + 1);
    inst->model_exchange = model_exchange ? 1 : 0;
    inst->log_adapter = adapter;
    inst->importer_logger = importer_logger;
    inst->importer_env = importer_env;
    inst->logging_on = logging_on ? 1 : 0;
    inst->log_events = 1;
    inst->worst_status = FL_OK;
    if (!read_start_values(fn, inst, resources, resources_is_uri)) {
        free(inst->name);
        free(inst);
        return NULL;
    }
    set_start_values(inst);
    fl_log(inst, FL_OK, "%s: instance \"%s\" of %s created for %s", fn, inst->name,
           MODEL_IDENTIFIER_STR, model_exchange ? "Model Exchange" : "Co-Simulation");
    return inst;
}

WMR_INTERNAL
void fl_free(FlInstance *inst) {
    if (!inst) return;
    free(inst->name);
    free(inst);
}

/* ------------------------------------------------------------------------ */
/* life cycle                                                               */
/* ------------------------------------------------------------------------ */

WMR_INTERNAL
FlStatus fl_setup_experiment(const char *fn, FlInstance *inst, int tolerance_defined,
                             double tolerance, double start_time, int stop_time_defined,
                             double stop_time) {
    FlData *d;
    double rtol = SOLVER_DEFAULT_RTOL, atol = SOLVER_DEFAULT_ATOL;
    if (!fl_check_state(fn, inst, FL_INSTANTIATED)) return FL_ERROR;
    d = &inst->d;
    if (!isfinite(start_time)) {
        fl_log(inst, FL_ERROR, "%s: startTime = %g is not a finite number", fn, start_time);
        return ret(inst, FL_ERROR);
    }
    if (stop_time_defined && (!isfinite(stop_time) || stop_time < start_time)) {
        fl_log(inst, FL_ERROR, "%s: stopTime = %g must be finite and >= startTime = %g", fn,
               stop_time, start_time);
        return ret(inst, FL_ERROR);
    }
    if (tolerance_defined) {
        if (!isfinite(tolerance) || !(tolerance > 0.0)) {
            fl_log(inst, FL_ERROR, "%s: tolerance = %g must be a positive finite number", fn,
                   tolerance);
            return ret(inst, FL_ERROR);
        }
        rtol = tolerance;
        if (rtol < 1e-12) rtol = 1e-12;
        if (rtol > 1e-2) rtol = 1e-2;
        atol = 0.1 * rtol;
        if (rtol != tolerance)
            fl_log(inst, FL_OK, "%s: tolerance %g clipped to %g", fn, tolerance, rtol);
    }
    d->solver.rtol = rtol;
    d->solver.atol = atol;
    d->start_time = start_time;
    d->time = start_time;
    d->stop_time_defined = stop_time_defined ? 1 : 0;
    d->stop_time = stop_time_defined ? stop_time : 0.0;
    if (stop_time_defined)
        fl_log(inst, FL_OK, "%s: startTime = %g, stopTime = %g, rtol = %g, atol = %g", fn,
               start_time, stop_time, rtol, atol);
    else
        fl_log(inst, FL_OK, "%s: startTime = %g, no stopTime, rtol = %g, atol = %g", fn,
               start_time, rtol, atol);
    return FL_OK;
}

WMR_INTERNAL
FlStatus fl_enter_initialization_mode(const char *fn, FlInstance *inst) {
    if (!fl_check_state(fn, inst, FL_INSTANTIATED)) return FL_ERROR;
    inst->d.mode = FL_INITIALIZATION_MODE;
    inst->d.time = inst->d.start_time;
    inst->d.outputs_dirty = 1;
    return FL_OK;
}

WMR_INTERNAL
FlStatus fl_exit_initialization_mode(const char *fn, FlInstance *inst) {
    FlData *d;
    double x[MODEL_NX], dx[MODEL_NX], y[MODEL_NY];
    int i;
    if (!fl_check_state(fn, inst, FL_INITIALIZATION_MODE)) return FL_ERROR;
    d = &inst->d;
    if (!compute_initial_state(fn, inst, x)) return fail(inst);
    if (model_derivatives(x, d->u, d->p, dx) != 0) {
        fl_log(inst, FL_ERROR, "%s: model_derivatives failed at the initial state", fn);
        return fail(inst);
    }
    if ((i = find_nonfinite(dx, MODEL_NX)) >= 0) {
        fl_log(inst, FL_ERROR,
               "%s: derivative of state %d = %g is not a finite number at the initial state "
               "(t = %g); check the parameters (e.g. a singular mass matrix)",
               fn, i, dx[i], d->start_time);
        return fail(inst);
    }
    if (!compute_outputs(fn, inst, x, y)) return fail(inst);
    memcpy(d->x, x, sizeof(x));
    memcpy(d->y, y, sizeof(y));
    memcpy(d->y_held, y, sizeof(y));
    d->outputs_dirty = 0;
    d->time = d->start_time;
    d->n_comm_steps = 0;
    d->n_samples = 0;
    d->run_over = 0;
    solver_reset_hint(&d->solver);
    d->mode = inst->model_exchange ? FL_EVENT_MODE : FL_STEP_MODE;
    fl_log(inst, FL_OK, "%s: initialised at t = %g", fn, d->time);
    return FL_OK;
}

WMR_INTERNAL
FlStatus fl_terminate(const char *fn, FlInstance *inst) {
    FlData *d;
    if (!fl_check_state(fn, inst, FL_SIMULATING)) return FL_ERROR;
    d = &inst->d;
    d->mode = FL_TERMINATED;
    if (inst->model_exchange)
        fl_log(inst, FL_OK, "%s: terminated at t = %.17g after %lu completed integrator steps",
               fn, d->time, d->n_comm_steps);
    else
        fl_log(inst, FL_OK,
               "%s: terminated at t = %.17g after %lu communication steps (%lu internal steps "
               "accepted, %lu rejected, %lu derivative evaluations)",
               fn, d->time, d->n_comm_steps, d->solver.n_accepted, d->solver.n_rejected,
               d->solver.n_rhs);
    return FL_OK;
}

WMR_INTERNAL
FlStatus fl_reset(const char *fn, FlInstance *inst) {
    if (!fl_check_state(fn, inst, FL_ANY_STATE)) return FL_ERROR;
    set_start_values(inst);
    inst->worst_status = FL_OK;
    fl_log(inst, FL_OK, "%s: reset to the start values", fn);
    return FL_OK;
}

/* ------------------------------------------------------------------------ */
/* variables                                                                */
/* ------------------------------------------------------------------------ */

static int check_vrs(const char *fn, FlInstance *inst, const unsigned int vr[], size_t nvr,
                     const void *values) {
    size_t k;
    int ok = 1;
    if (nvr == 0) return 1;
    if (!vr) {
        fl_log(inst, FL_ERROR, "%s: the value reference array is NULL", fn);
        return 0;
    }
    if (!values) {
        fl_log(inst, FL_ERROR, "%s: the value array is NULL", fn);
        return 0;
    }
    for (k = 0; k < nvr; k++) {
        if (vr[k] >= (unsigned int)MODEL_NV) {
            fl_log(inst, FL_ERROR, "%s: value reference %u does not exist (valid: 0 to %d)", fn,
                   vr[k], MODEL_NV - 1);
            ok = 0;
        }
    }
    return ok;
}

WMR_INTERNAL
FlStatus fl_get_real(const char *fn, FlInstance *inst, const unsigned int vr[], size_t nvr,
                     double values[]) {
    FlStatus status = FL_OK;
    size_t k;
    double dx[MODEL_NX + 1];
    int have_dx = 0;
    if (!fl_check_state(fn, inst, FL_GET_MASK)) return FL_ERROR;
    if (!check_vrs(fn, inst, vr, nvr, values)) return ret(inst, FL_ERROR);
    if (nvr == 0) return FL_OK;
    if (!update_outputs(fn, inst)) status = FL_ERROR; /* last good values are returned */
    for (k = 0; k < nvr; k++) {
        if (MODEL_VARIABLES[vr[k]].kind == MODEL_VAR_DERIVATIVE && !have_dx) {
            /* only asked for by Model Exchange importers: computed here, not on every step */
            if (!compute_derivatives(fn, inst, dx)) {
                memset(dx, 0, sizeof(dx));
                status = FL_ERROR;
            }
            have_dx = 1;
        }
    }
    for (k = 0; k < nvr; k++) {
        const ModelVariable *mv = &MODEL_VARIABLES[vr[k]];
        switch (mv->kind) {
        case MODEL_VAR_TIME: values[k] = inst->d.time; break;
        case MODEL_VAR_PARAMETER: values[k] = inst->d.p[mv->index]; break;
        case MODEL_VAR_INPUT: values[k] = inst->d.u[mv->index]; break;
        case MODEL_VAR_OUTPUT: values[k] = inst->d.y[mv->index]; break;
        case MODEL_VAR_DERIVATIVE: values[k] = dx[mv->index]; break;
        }
    }
    return ret(inst, status);
}

WMR_INTERNAL
FlStatus fl_set_real(const char *fn, FlInstance *inst, const unsigned int vr[], size_t nvr,
                     const double values[]) {
    FlData *d;
    size_t k;
    int ok;
    if (!fl_check_state(fn, inst, FL_SET_MASK)) return FL_ERROR;
    if (!check_vrs(fn, inst, vr, nvr, values)) return ret(inst, FL_ERROR);
    d = &inst->d;
    /* validate everything first: all or nothing */
    ok = 1;
    for (k = 0; k < nvr; k++) {
        const ModelVariable *mv = &MODEL_VARIABLES[vr[k]];
        double v = values[k];
        if (mv->kind != MODEL_VAR_PARAMETER && mv->kind != MODEL_VAR_INPUT) {
            fl_log(inst, FL_ERROR, "%s: %s (value reference %u) is a%s %s and cannot be set%s",
                   fn, mv->name, vr[k], mv->kind != MODEL_VAR_DERIVATIVE ? "n" : "",
                   kind_name(mv->kind),
                   mv->state >= 0 ? " (it is a continuous state: use SetContinuousStates)" : "");
            ok = 0;
            continue;
        }
        if (mv->kind == MODEL_VAR_PARAMETER && d->mode == FL_CONTINUOUS_TIME_MODE) {
            fl_log(inst, FL_ERROR,
                   "%s: %s (value reference %u) is a parameter; in ContinuousTimeMode only "
                   "inputs can be set (enter EventMode first)",
                   fn, mv->name, vr[k]);
            ok = 0;
            continue;
        }
        if (mv->kind == MODEL_VAR_PARAMETER && (d->mode & FL_SIMULATING) && !mv->tunable) {
            fl_log(inst, FL_ERROR,
                   "%s: %s (value reference %u) is not a tunable parameter; it can only be set "
                   "before the end of initialisation",
                   fn, mv->name, vr[k]);
            ok = 0;
            continue;
        }
        if (!isfinite(v)) {
            fl_log(inst, FL_ERROR, "%s: %s = %g is not a finite number", fn, mv->name, v);
            ok = 0;
            continue;
        }
        if (v < mv->min) {
            fl_log(inst, FL_ERROR, "%s: %s = %.17g is below its minimum %.17g (bounds [%g, %g])",
                   fn, mv->name, v, mv->min, mv->min, mv->max);
            ok = 0;
        } else if (v > mv->max) {
            fl_log(inst, FL_ERROR, "%s: %s = %.17g is above its maximum %.17g (bounds [%g, %g])",
                   fn, mv->name, v, mv->max, mv->min, mv->max);
            ok = 0;
        }
    }
    if (!ok) return ret(inst, FL_ERROR);
    for (k = 0; k < nvr; k++) {
        const ModelVariable *mv = &MODEL_VARIABLES[vr[k]];
        if (mv->kind == MODEL_VAR_PARAMETER) d->p[mv->index] = values[k];
        else d->u[mv->index] = values[k];
    }
    if (nvr > 0) d->outputs_dirty = 1;
    return FL_OK;
}

/* ------------------------------------------------------------------------ */
/* stepping                                                                 */
/* ------------------------------------------------------------------------ */

WMR_INTERNAL
FlStatus fl_get_time(const char *fn, FlInstance *inst, double *time) {
    if (!fl_check_state(fn, inst, FL_ANY_STATE)) return FL_ERROR;
    if (!time) {
        fl_log(inst, FL_ERROR, "%s: value pointer is NULL", fn);
        return ret(inst, FL_ERROR);
    }
    *time = inst->d.time;
    return FL_OK;
}

WMR_INTERNAL
FlStatus fl_do_step(const char *fn, FlInstance *inst, double tc, double h,
                    double *last_successful_time) {
    FlData *d;
    double x[MODEL_NX], y[MODEL_NY], t_end, tol;
    char msg[FL_MSG_SIZE];
    SolverStatus st;
#if MODEL_SAMPLED
    unsigned long n = 0; /* samples taken by the end of the step */
    int over = 0;        /* a sample ended the run (model_run_over) */
#endif

    if (inst && last_successful_time) *last_successful_time = inst->d.time;
    if (!fl_check_state(fn, inst, FL_STEP_MODE)) return FL_ERROR;
    d = &inst->d;

    if (!isfinite(h) || !(h > 0.0)) {
        fl_log(inst, FL_ERROR, "%s: communicationStepSize = %g must be a positive finite number",
               fn, h);
        return ret(inst, FL_ERROR);
    }
    tol = time_tol(d->time);
    if (!isfinite(tc) || fabs(tc - d->time) > tol) {
        fl_log(inst, FL_ERROR,
               "%s: currentCommunicationPoint = %.17g does not match the instance time: expected "
               "%.17g (difference %g, tolerance %g)",
               fn, tc, d->time, tc - d->time, tol);
        return ret(inst, FL_ERROR);
    }
    t_end = tc + h;
    if (d->stop_time_defined &&
        t_end > d->stop_time + time_tol(d->stop_time)) {
        fl_log(inst, FL_ERROR, "%s: the step [%.17g, %.17g] ends after stopTime = %.17g", fn, tc,
               t_end, d->stop_time);
        return ret(inst, FL_ERROR);
    }

#if MODEL_SAMPLED
    {
        /* Every grid point in [tc, t_end) is a sample, with the inputs set at tc held over the
         * step (canInterpolateInputs is false): k periods in one step are k single steps
         * without a set in between.  A step between grid points takes none. */
        double z[MODEL_NX], ys[MODEL_NY];
        int i;
        memcpy(z, d->x, sizeof(z));
        memcpy(ys, d->y_held, sizeof(ys));
        n = d->n_samples;
        over = d->run_over;
        st = SOLVER_OK;
        msg[0] = '\0';
        while (st == SOLVER_OK && sample_time(d, n) < t_end - time_tol(t_end)) {
            if (over) { /* after the run's end every sample holds the plant still */
                if (model_rest(z, d->u, d->p, ys, x) != 0 || find_nonfinite(ys, MODEL_NY) >= 0
                    || find_nonfinite(x, MODEL_NX) >= 0) {
                    st = SOLVER_NONFINITE;
                    snprintf(msg, sizeof(msg), "the sample at rest at t = %.17g failed",
                             sample_time(d, n));
                    break;
                }
                memcpy(z, x, sizeof(z));
                n++;
                continue;
            }
            if (n == d->n_samples && !d->outputs_dirty && sample_due(d)) {
                memcpy(ys, d->y, sizeof(ys)); /* the sample at tc, already read by the master */
            } else if (!compute_outputs(fn, inst, z, ys)) {
                st = SOLVER_NONFINITE;
                snprintf(msg, sizeof(msg), "the sample at t = %.17g failed",
                         sample_time(d, n));
                break;
            }
            if (!over && model_run_over(ys)) {
                over = 1; /* this sample's outputs were the law's; the next ones are at rest */
                fl_log(inst, FL_OK, "%s: the run ended at t = %.17g: the master is asked to "
                       "stop, and the later samples hold the plant still", fn,
                       sample_time(d, n));
            }
            if (model_update(z, d->u, d->p, x) != 0) {
                st = SOLVER_MODEL_ERROR;
                snprintf(msg, sizeof(msg), "model_update failed at t = %.17g", sample_time(d, n));
            } else if ((i = find_nonfinite(x, MODEL_NX)) >= 0) {
                st = SOLVER_NONFINITE;
                snprintf(msg, sizeof(msg), "model_update gave a non-finite discrete state %d at "
                         "t = %.17g", i, sample_time(d, n));
            } else {
                memcpy(z, x, sizeof(z));
                n++;
            }
        }
        if (st == SOLVER_OK) {
            memcpy(x, z, sizeof(x));
            memcpy(y, ys, sizeof(y));
        }
    }
#else
    memcpy(x, d->x, sizeof(x));
    st = solver_integrate(&d->solver, tc, t_end, x, d->u, d->p, msg, sizeof(msg));
#endif
    if (st != SOLVER_OK) {
        fl_log(inst, FL_ERROR,
               "%s: integration from t = %.17g to %.17g failed (%s): %s; the last good state at "
               "t = %.17g is kept",
               fn, tc, t_end, solver_status_name(st), msg, d->time);
        return fail(inst);
    }
#if MODEL_SAMPLED
    /* the outputs at t_end follow from the new state: the next sample g(z, u) if t_end is on
     * the grid, else the last sample held (evaluated on the next get) */
    d->n_samples = n;
    d->run_over = over;
    memcpy(d->x, x, sizeof(x));
    memcpy(d->y_held, y, sizeof(y));
    d->outputs_dirty = 1;
#else
    if (!compute_outputs(fn, inst, x, y)) {
        fl_log(inst, FL_ERROR, "%s: the last good state at t = %.17g is kept", fn, d->time);
        return fail(inst);
    }
    memcpy(d->x, x, sizeof(x));
    memcpy(d->y, y, sizeof(y));
    d->outputs_dirty = 0;
#endif
    d->time = t_end; /* set, never accumulated over internal steps */
    d->n_comm_steps++;
    if (last_successful_time) *last_successful_time = d->time;
    return FL_OK;
}

/* ------------------------------------------------------------------------ */
/* Model Exchange                                                           */
/* ------------------------------------------------------------------------ */

/* The model has no events: the event iteration is empty and every mode switch is trivial. */

WMR_INTERNAL
FlStatus fl_enter_event_mode(const char *fn, FlInstance *inst) {
    if (!fl_check_state(fn, inst, FL_CONTINUOUS_TIME_MODE)) return FL_ERROR;
    inst->d.mode = FL_EVENT_MODE;
    return FL_OK;
}

WMR_INTERNAL
FlStatus fl_update_discrete_states(const char *fn, FlInstance *inst) {
    return fl_check_state(fn, inst, FL_EVENT_MODE) ? FL_OK : FL_ERROR;
}

WMR_INTERNAL
FlStatus fl_enter_continuous_time_mode(const char *fn, FlInstance *inst) {
    if (!fl_check_state(fn, inst, FL_EVENT_MODE)) return FL_ERROR;
    inst->d.mode = FL_CONTINUOUS_TIME_MODE;
    return FL_OK;
}

WMR_INTERNAL
FlStatus fl_completed_integrator_step(const char *fn, FlInstance *inst) {
    if (!fl_check_state(fn, inst, FL_CONTINUOUS_TIME_MODE)) return FL_ERROR;
    inst->d.n_comm_steps++; /* accepted integrator steps, reported by terminate */
    return FL_OK;
}

WMR_INTERNAL
FlStatus fl_set_time(const char *fn, FlInstance *inst, double time) {
    if (!fl_check_state(fn, inst, FL_EVENT_MODE | FL_CONTINUOUS_TIME_MODE)) return FL_ERROR;
    if (!isfinite(time)) {
        fl_log(inst, FL_ERROR, "%s: time = %g is not a finite number", fn, time);
        return ret(inst, FL_ERROR);
    }
    inst->d.time = time;
    inst->d.outputs_dirty = 1;
    return FL_OK;
}

/* The length of a state vector argument must be MODEL_NX. */
static int check_nx(const char *fn, FlInstance *inst, const void *values, size_t n) {
    if (n != (size_t)MODEL_NX) {
        fl_log(inst, FL_ERROR, "%s: nContinuousStates = %lu, the model has %d", fn,
               (unsigned long)n, MODEL_NX);
        return 0;
    }
    if (n > 0 && !values) {
        fl_log(inst, FL_ERROR, "%s: the value array is NULL", fn);
        return 0;
    }
    return 1;
}

#define FL_STATES_GET_MASK (FL_INITIALIZATION_MODE | FL_EVENT_MODE | FL_CONTINUOUS_TIME_MODE | \
                            FL_TERMINATED | FL_ERROR_STATE)

WMR_INTERNAL
FlStatus fl_set_continuous_states(const char *fn, FlInstance *inst, const double x[],
                                  size_t n) {
    int i;
    if (!fl_check_state(fn, inst, FL_EVENT_MODE | FL_CONTINUOUS_TIME_MODE)) return FL_ERROR;
    if (!check_nx(fn, inst, x, n)) return ret(inst, FL_ERROR);
    if ((i = find_nonfinite(x, MODEL_NX)) >= 0) {
        fl_log(inst, FL_ERROR, "%s: state %d = %g is not a finite number", fn, i, x[i]);
        return ret(inst, FL_ERROR);
    }
    memcpy(inst->d.x, x, n * sizeof(double));
    inst->d.outputs_dirty = 1;
    return FL_OK;
}

WMR_INTERNAL
FlStatus fl_get_continuous_states(const char *fn, FlInstance *inst, double x[], size_t n) {
    FlStatus status = FL_OK;
    if (!fl_check_state(fn, inst, FL_STATES_GET_MASK)) return FL_ERROR;
    if (!check_nx(fn, inst, x, n)) return ret(inst, FL_ERROR);
    if (!update_outputs(fn, inst)) status = FL_ERROR; /* the initial state from p */
    memcpy(x, inst->d.x, n * sizeof(double));
    return ret(inst, status);
}

WMR_INTERNAL
FlStatus fl_get_derivatives(const char *fn, FlInstance *inst, double dx[], size_t n) {
    if (!fl_check_state(fn, inst, FL_STATES_GET_MASK)) return FL_ERROR;
    if (!check_nx(fn, inst, dx, n)) return ret(inst, FL_ERROR);
    return compute_derivatives(fn, inst, dx) ? FL_OK : ret(inst, FL_ERROR);
}

WMR_INTERNAL
FlStatus fl_get_nominals(const char *fn, FlInstance *inst, double nominals[], size_t n) {
    size_t i;
    if (!fl_check_state(fn, inst, FL_ANY_STATE)) return FL_ERROR;
    if (!check_nx(fn, inst, nominals, n)) return ret(inst, FL_ERROR);
    for (i = 0; i < n; i++) nominals[i] = 1.0; /* the states are O(1) in SI units */
    return FL_OK;
}

WMR_INTERNAL
FlStatus fl_get_event_indicators(const char *fn, FlInstance *inst, double indicators[],
                                 size_t n) {
    (void)indicators;
    if (!fl_check_state(fn, inst, FL_STATES_GET_MASK)) return FL_ERROR;
    if (n != 0) {
        fl_log(inst, FL_ERROR, "%s: nEventIndicators = %lu, the model has none", fn,
               (unsigned long)n);
        return ret(inst, FL_ERROR);
    }
    return FL_OK;
}

/* ------------------------------------------------------------------------ */
/* variable dependencies                                                    */
/* ------------------------------------------------------------------------ */

WMR_INTERNAL
FlStatus fl_variable_dependencies(const char *fn, FlInstance *inst, unsigned int vr, size_t *n,
                                  unsigned int knowns[], int kinds[], size_t n_given) {
    int r, initial, k;
    if (!fl_check_state(fn, inst, FL_ANY_STATE)) return FL_ERROR;
    if (!n && !knowns) {
        fl_log(inst, FL_ERROR, "%s: nDependencies is NULL", fn);
        return ret(inst, FL_ERROR);
    }
    if (vr >= (unsigned int)MODEL_NV) {
        fl_log(inst, FL_ERROR, "%s: value reference %u does not exist (valid: 0 to %d)", fn, vr,
               MODEL_NV - 1);
        return ret(inst, FL_ERROR);
    }
    /* before the end of initialisation the initial unknowns' dependencies apply */
    initial = (inst->d.mode & (FL_INSTANTIATED | FL_INITIALIZATION_MODE)) != 0;
    for (r = 0; r < MODEL_N_DEPENDENCY_ROWS; r++) {
        const ModelDependencyRow *row = &MODEL_DEPENDENCY_ROWS[r];
        if (row->unknown != vr || row->initial != initial) continue;
        if (n) *n = (size_t)row->count;
        if (!knowns) return FL_OK;
        if (n_given != (size_t)row->count || (row->count > 0 && !kinds)) {
            fl_log(inst, FL_ERROR, "%s: nDependencies = %lu, %s has %d (ask "
                   "fmi3GetNumberOfVariableDependencies first)", fn, (unsigned long)n_given,
                   MODEL_VARIABLES[vr].name, row->count);
            return ret(inst, FL_ERROR);
        }
        for (k = 0; k < row->count; k++) {
            knowns[k] = MODEL_DEPENDENCY_KNOWNS[row->first + k];
            kinds[k] = MODEL_DEPENDENCY_KINDS[row->first + k];
        }
        return FL_OK;
    }
    fl_log(inst, FL_ERROR, "%s: %s (value reference %u) is not %s of the model structure", fn,
           MODEL_VARIABLES[vr].name, vr,
           initial ? "an initial unknown (InitialUnknown)"
                   : "an output or a state derivative (Output, ContinuousStateDerivative)");
    return ret(inst, FL_ERROR);
}

/* ------------------------------------------------------------------------ */
/* partial derivatives                                                      */
/* ------------------------------------------------------------------------ */

#if MODEL_PROVIDES_JACOBIAN
/* Row of the Jacobian for an unknown (state derivative or output), -1 if it is none. */
static int jac_row(unsigned int vr) {
    const ModelVariable *mv = &MODEL_VARIABLES[vr];
    if (mv->kind == MODEL_VAR_DERIVATIVE) return mv->index;
    if (mv->kind == MODEL_VAR_OUTPUT) return MODEL_NX + mv->index;
    return -1;
}

/* Column of the Jacobian for a known (continuous state or input), -1 if it is none. */
static int jac_col(unsigned int vr) {
    const ModelVariable *mv = &MODEL_VARIABLES[vr];
    if (mv->kind == MODEL_VAR_OUTPUT && mv->state >= 0) return mv->state;
    if (mv->kind == MODEL_VAR_INPUT) return MODEL_NX + mv->index;
    return -1;
}

static int check_partial_vrs(const char *fn, FlInstance *inst, const unsigned int vr[], size_t n,
                             int unknown) {
    size_t k;
    for (k = 0; k < n; k++) {
        if (vr[k] >= (unsigned int)MODEL_NV) {
            fl_log(inst, FL_ERROR, "%s: value reference %u does not exist (valid: 0 to %d)", fn,
                   vr[k], MODEL_NV - 1);
            return 0;
        }
        if ((unknown ? jac_row(vr[k]) : jac_col(vr[k])) < 0) {
            fl_log(inst, FL_ERROR,
                   unknown ? "%s: %s (value reference %u) is not an unknown: give outputs or "
                             "state derivatives"
                           : "%s: %s (value reference %u) is not a known: give continuous "
                             "states or inputs",
                   fn, MODEL_VARIABLES[vr[k]].name, vr[k]);
            return 0;
        }
    }
    return 1;
}
#endif

WMR_INTERNAL
FlStatus fl_partial_derivative(const char *fn, FlInstance *inst,
                               const unsigned int unknowns[], size_t n_unknowns,
                               const unsigned int knowns[], size_t n_knowns,
                               const double seed[], double sensitivity[],
                               int adjoint) {
#if MODEL_PROVIDES_JACOBIAN
    FlData *d;
    double jac[MODEL_JAC_ROWS * MODEL_JAC_COLS + 1];
    size_t i, j;
    if (!fl_check_state(fn, inst, FL_SIMULATING | FL_TERMINATED | FL_ERROR_STATE)) {
        if (inst && inst->d.mode == FL_INITIALIZATION_MODE)
            fl_log(inst, FL_ERROR, "%s: partial derivatives are provided after "
                                   "initialisation (the knowns are the states and inputs)", fn);
        return FL_ERROR;
    }
    d = &inst->d;
    if ((n_unknowns > 0 && !unknowns) || (n_knowns > 0 && !knowns) ||
        ((adjoint ? n_unknowns : n_knowns) > 0 && !seed) ||
        ((adjoint ? n_knowns : n_unknowns) > 0 && !sensitivity)) {
        fl_log(inst, FL_ERROR, "%s: an array argument is NULL", fn);
        return ret(inst, FL_ERROR);
    }
    if (!check_partial_vrs(fn, inst, unknowns, n_unknowns, 1) ||
        !check_partial_vrs(fn, inst, knowns, n_knowns, 0))
        return ret(inst, FL_ERROR);
    if (model_jacobian(d->x, d->u, d->p, jac) != 0 ||
        find_nonfinite(jac, MODEL_JAC_ROWS * MODEL_JAC_COLS) >= 0) {
        fl_log(inst, FL_ERROR, "%s: the Jacobian is not finite at t = %.17g", fn, d->time);
        return ret(inst, FL_ERROR);
    }
    if (adjoint) {
        for (j = 0; j < n_knowns; j++) {
            double sum = 0.0;
            int col = jac_col(knowns[j]);
            for (i = 0; i < n_unknowns; i++)
                sum += seed[i] * jac[col * MODEL_JAC_ROWS + jac_row(unknowns[i])];
            sensitivity[j] = sum;
        }
    } else {
        for (i = 0; i < n_unknowns; i++) {
            double sum = 0.0;
            int row = jac_row(unknowns[i]);
            for (j = 0; j < n_knowns; j++)
                sum += jac[jac_col(knowns[j]) * MODEL_JAC_ROWS + row] * seed[j];
            sensitivity[i] = sum;
        }
    }
    return FL_OK;
#else
    (void)unknowns; (void)n_unknowns; (void)knowns; (void)n_knowns; (void)seed;
    (void)sensitivity; (void)adjoint;
    return fl_unsupported(fn, inst, "the model core provides no Jacobian");
#endif
}

/* ------------------------------------------------------------------------ */
/* FMU state                                                                */
/* ------------------------------------------------------------------------ */

static const char STATE_MAGIC[8] = {'W', 'M', 'R', 'S', 'T', 'A', 'T', 'E'};
static const char BLOB_MAGIC[8] = {'W', 'M', 'R', 'F', 'M', 'U', 'S', 'T'};
#define BLOB_FORMAT_VERSION 4u /* 2: Model Exchange modes; 3: the sample grid; 4: the run's end */

typedef struct {
    char magic[8];
    FlData d;
} FlSavedState;

/* header: magic[8], format version, NX, NP, NU, NY, sizeof(FlData), token length */
#define BLOB_N_FIELDS 7
#define BLOB_HEADER_SIZE (8 + 4 * BLOB_N_FIELDS)

static int valid_saved_data(const FlData *d) {
    switch (d->mode) {
    case FL_INSTANTIATED: case FL_INITIALIZATION_MODE: case FL_STEP_MODE:
    case FL_TERMINATED: case FL_ERROR_STATE: case FL_EVENT_MODE: case FL_CONTINUOUS_TIME_MODE:
        break;
    default: return 0;
    }
    if (!isfinite(d->time)) return 0;
    if (find_nonfinite(d->x, MODEL_NX) >= 0 || find_nonfinite(d->u, MODEL_NU) >= 0 ||
        find_nonfinite(d->p, MODEL_NP) >= 0 || find_nonfinite(d->y, MODEL_NY) >= 0)
        return 0;
    return 1;
}

static int check_saved(const char *fn, FlInstance *inst, const void *state) {
    const FlSavedState *s = (const FlSavedState *)state;
    if (!s) {
        fl_log(inst, FL_ERROR, "%s: FMU state is NULL", fn);
        return 0;
    }
    if (memcmp(s->magic, STATE_MAGIC, sizeof(STATE_MAGIC)) != 0) {
        fl_log(inst, FL_ERROR, "%s: the FMU state was not created by this FMU", fn);
        return 0;
    }
    return 1;
}

/* The state to write into: the importer's previous one (checked), or a new one. */
static FlSavedState *state_slot(const char *fn, FlInstance *inst, void *previous) {
    FlSavedState *s;
    if (previous) {
        return check_saved(fn, inst, previous) ? (FlSavedState *)previous : NULL;
    }
    s = (FlSavedState *)calloc(1, sizeof(FlSavedState));
    if (!s) {
        fl_log(inst, FL_ERROR, "%s: out of memory", fn);
        return NULL;
    }
    memcpy(s->magic, STATE_MAGIC, sizeof(STATE_MAGIC));
    return s;
}

WMR_INTERNAL
FlStatus fl_get_fmu_state(const char *fn, FlInstance *inst, void **state) {
    FlSavedState *s;
    if (!fl_check_state(fn, inst, FL_ANY_STATE)) return FL_ERROR;
    if (!state) {
        fl_log(inst, FL_ERROR, "%s: FMUState pointer is NULL", fn);
        return ret(inst, FL_ERROR);
    }
    s = state_slot(fn, inst, *state);
    if (!s) return ret(inst, FL_ERROR);
    memcpy(&s->d, &inst->d, sizeof(FlData));
    *state = s;
    return FL_OK;
}

WMR_INTERNAL
FlStatus fl_set_fmu_state(const char *fn, FlInstance *inst, const void *state) {
    const FlSavedState *s;
    if (!fl_check_state(fn, inst, FL_ANY_STATE)) return FL_ERROR;
    if (!check_saved(fn, inst, state)) return ret(inst, FL_ERROR);
    s = (const FlSavedState *)state;
    if ((s->d.mode & (inst->model_exchange ? FL_STEP_MODE
                                           : FL_EVENT_MODE | FL_CONTINUOUS_TIME_MODE))) {
        fl_log(inst, FL_ERROR, "%s: the FMU state (%s) belongs to a %s instance", fn,
               fl_mode_name(s->d.mode), inst->model_exchange ? "Co-Simulation" : "Model Exchange");
        return ret(inst, FL_ERROR);
    }
    memcpy(&inst->d, &s->d, sizeof(FlData));
    return FL_OK;
}

WMR_INTERNAL
FlStatus fl_free_fmu_state(const char *fn, FlInstance *inst, void **state) {
    if (!fl_check_state(fn, inst, FL_ANY_STATE)) return FL_ERROR;
    if (!state || !*state) return FL_OK;
    if (!check_saved(fn, inst, *state)) return ret(inst, FL_ERROR);
    memset(*state, 0, sizeof(STATE_MAGIC)); /* catch double frees of stale copies */
    free(*state);
    *state = NULL;
    return FL_OK;
}

static size_t blob_size(void) {
    return BLOB_HEADER_SIZE + strlen(MODEL_INSTANTIATION_TOKEN) + sizeof(FlData);
}

WMR_INTERNAL
FlStatus fl_serialized_size(const char *fn, FlInstance *inst, const void *state, size_t *size) {
    if (!fl_check_state(fn, inst, FL_ANY_STATE)) return FL_ERROR;
    if (!check_saved(fn, inst, state)) return ret(inst, FL_ERROR);
    if (!size) {
        fl_log(inst, FL_ERROR, "%s: size pointer is NULL", fn);
        return ret(inst, FL_ERROR);
    }
    *size = blob_size();
    return FL_OK;
}

static void put_u32(unsigned char *b, uint32_t v) { memcpy(b, &v, 4); }
static uint32_t get_u32(const unsigned char *b) {
    uint32_t v;
    memcpy(&v, b, 4);
    return v;
}

static void header_fields(uint32_t f[BLOB_N_FIELDS]) {
    f[0] = BLOB_FORMAT_VERSION;
    f[1] = MODEL_NX;
    f[2] = MODEL_NP;
    f[3] = MODEL_NU;
    f[4] = MODEL_NY;
    f[5] = (uint32_t)sizeof(FlData);
    f[6] = (uint32_t)strlen(MODEL_INSTANTIATION_TOKEN);
}

WMR_INTERNAL
FlStatus fl_serialize(const char *fn, FlInstance *inst, const void *state,
                      unsigned char *buffer, size_t size) {
    const FlSavedState *s;
    uint32_t f[BLOB_N_FIELDS];
    size_t need = blob_size(), pos, tlen = strlen(MODEL_INSTANTIATION_TOKEN);
    int i;
    if (!fl_check_state(fn, inst, FL_ANY_STATE)) return FL_ERROR;
    if (!check_saved(fn, inst, state)) return ret(inst, FL_ERROR);
    if (!buffer || size < need) {
        fl_log(inst, FL_ERROR, "%s: buffer too small: %lu bytes given, %lu needed", fn,
               (unsigned long)(buffer ? size : 0), (unsigned long)need);
        return ret(inst, FL_ERROR);
    }
    s = (const FlSavedState *)state;
    header_fields(f);
    memcpy(buffer, BLOB_MAGIC, 8);
    pos = 8;
    for (i = 0; i < BLOB_N_FIELDS; i++, pos += 4) put_u32(buffer + pos, f[i]);
    memcpy(buffer + pos, MODEL_INSTANTIATION_TOKEN, tlen);
    pos += tlen;
    memcpy(buffer + pos, &s->d, sizeof(FlData));
    return FL_OK;
}

WMR_INTERNAL
FlStatus fl_deserialize(const char *fn, FlInstance *inst, const unsigned char *buffer,
                        size_t size, void **state) {
    static const char *const field_names[BLOB_N_FIELDS] = {
        "format version", "MODEL_NX", "MODEL_NP", "MODEL_NU", "MODEL_NY", "state size",
        "instantiation token length"};
    uint32_t f[BLOB_N_FIELDS];
    size_t pos, tlen = strlen(MODEL_INSTANTIATION_TOKEN), need = blob_size();
    FlSavedState *s;
    FlData d;
    int i;
    if (!fl_check_state(fn, inst, FL_ANY_STATE)) return FL_ERROR;
    if (!state) {
        fl_log(inst, FL_ERROR, "%s: FMUState pointer is NULL", fn);
        return ret(inst, FL_ERROR);
    }
    if (!buffer || size < BLOB_HEADER_SIZE) {
        fl_log(inst, FL_ERROR, "%s: serialized state truncated: %lu bytes, header needs %d", fn,
               (unsigned long)(buffer ? size : 0), BLOB_HEADER_SIZE);
        return ret(inst, FL_ERROR);
    }
    if (memcmp(buffer, BLOB_MAGIC, 8) != 0) {
        fl_log(inst, FL_ERROR, "%s: not a serialized state of this FMU (bad magic)", fn);
        return ret(inst, FL_ERROR);
    }
    header_fields(f);
    for (i = 0, pos = 8; i < BLOB_N_FIELDS; i++, pos += 4) {
        uint32_t v = get_u32(buffer + pos);
        if (v != f[i]) {
            fl_log(inst, FL_ERROR, "%s: serialized state of another FMU: %s is %lu, expected %lu",
                   fn, field_names[i], (unsigned long)v, (unsigned long)f[i]);
            return ret(inst, FL_ERROR);
        }
    }
    if (size != need) {
        fl_log(inst, FL_ERROR, "%s: serialized state has %lu bytes, expected %lu (%s)", fn,
               (unsigned long)size, (unsigned long)need, size < need ? "truncated" : "trailing bytes");
        return ret(inst, FL_ERROR);
    }
    if (memcmp(buffer + pos, MODEL_INSTANTIATION_TOKEN, tlen) != 0) {
        fl_log(inst, FL_ERROR, "%s: serialized state of another FMU: instantiation token differs",
               fn);
        return ret(inst, FL_ERROR);
    }
    pos += tlen;
    memcpy(&d, buffer + pos, sizeof(FlData));
    if (!valid_saved_data(&d)) {
        fl_log(inst, FL_ERROR, "%s: serialized state is corrupt (invalid mode or non-finite values)",
               fn);
        return ret(inst, FL_ERROR);
    }
    s = state_slot(fn, inst, *state);
    if (!s) return ret(inst, FL_ERROR);
    memcpy(&s->d, &d, sizeof(FlData));
    *state = s;
    return FL_OK;
}
