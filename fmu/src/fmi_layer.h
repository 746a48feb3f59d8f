/*
 * fmi_layer.h: the FMI-version-independent layer (Co-Simulation and Model Exchange).
 *
 * fmi2.c and fmi3.c are thin shells that translate their arguments and call
 * these functions.  The layer owns the instance (state machine, variables,
 * solver), validates every call and every value, and reports through a
 * version-specific log adapter.  It only knows the model contract (model.h).
 *
 * Every function takes the name of the calling FMI function (fn) so that
 * messages read "fmi3DoStep: expected state StepMode, was Instantiated".
 */
#ifndef WMR_FMI_LAYER_H
#define WMR_FMI_LAYER_H

#include <stddef.h>

#include "model.h"
#include "solver.h"

/* Same numbers as fmi2Status and fmi3Status (OK, Warning, Discard, Error, Fatal). */
typedef enum {
    FL_OK = 0,
    FL_WARNING = 1,
    FL_DISCARD = 2,
    FL_ERROR = 3,
    FL_FATAL = 4
} FlStatus;

/* Instance states (bit flags, so that allowed states are masks). */
typedef enum {
    FL_INSTANTIATED = 1 << 0,
    FL_INITIALIZATION_MODE = 1 << 1,
    FL_STEP_MODE = 1 << 2,
    FL_TERMINATED = 1 << 3,
    FL_ERROR_STATE = 1 << 4,
    FL_EVENT_MODE = 1 << 5,          /* Model Exchange only */
    FL_CONTINUOUS_TIME_MODE = 1 << 6 /* Model Exchange only */
} FlMode;

#define FL_ANY_STATE (FL_INSTANTIATED | FL_INITIALIZATION_MODE | FL_STEP_MODE | FL_TERMINATED | \
                      FL_ERROR_STATE | FL_EVENT_MODE | FL_CONTINUOUS_TIME_MODE)
/* After initialisation, before termination: StepMode (CS), EventMode or ContinuousTimeMode (ME). */
#define FL_SIMULATING (FL_STEP_MODE | FL_EVENT_MODE | FL_CONTINUOUS_TIME_MODE)
/* Where variables may be read and written. */
#define FL_GET_MASK (FL_INITIALIZATION_MODE | FL_SIMULATING | FL_TERMINATED | FL_ERROR_STATE)
#define FL_SET_MASK (FL_INSTANTIATED | FL_INITIALIZATION_MODE | FL_SIMULATING)

/* Relative tolerance used to compare currentCommunicationPoint with the
 * instance time: |tc - t| <= FL_TIME_TOL * max(1, |t|). */
#define FL_TIME_TOL 1e-10

struct FlInstance;

/* Version-specific log adapter: forwards one message to the importer. */
typedef void (*FlLogAdapter)(const struct FlInstance *inst, FlStatus status,
                             const char *category, const char *message);

/* Everything that an FMU state captures: plain data, copied with memcpy. */
typedef struct {
    int mode;                 /* FlMode */
    double time;
    double start_time;
    double stop_time;
    int stop_time_defined;
    double x[MODEL_NX];
    double u[MODEL_NU];
    double p[MODEL_NP];
    double y[MODEL_NY];       /* last good outputs */
    int outputs_dirty;        /* y must be re-evaluated before it is read: set by every change
                                 of time, state, inputs or parameters, never a hold */
    SolverState solver;
    unsigned long n_comm_steps; /* doStep calls (CS) or completed integrator steps (ME) */
    /* sampled-data models (MODEL_SAMPLED): samples taken so far (the next is due at
     * start_time + n_samples * period) and the outputs of the last one, held between samples */
    unsigned long n_samples;
    double y_held[MODEL_NY];
    /* sampled-data models: 1 once a sample ended the run (model_run_over): no more samples,
     * the outputs held at rest, and the master asked to stop */
    int run_over;
} FlData;

typedef struct FlInstance {
    char *name;
    int model_exchange;            /* 1: instantiated for Model Exchange, 0: Co-Simulation */
    FlLogAdapter log_adapter;
    void (*importer_logger)(void); /* the importer's callback (cast back by the adapter) */
    void *importer_env;            /* componentEnvironment / instanceEnvironment */
    int logging_on;                /* debug logging on (fmiSetDebugLogging / instantiate) */
    int log_events;                /* category logEvents enabled: info messages */
    FlStatus worst_status;         /* worst status returned since instantiation/reset */
    /* the start values of the FMU's resources/start_values.txt (wmr ssp export writes it into
     * a package's FMUs, so that a master that sets no parameter runs the package's run):
     * parameters by value reference, applied over the compiled-in ones at every (re)start */
    int n_start_values;
    unsigned int start_vr[MODEL_NV];
    double start_value[MODEL_NV];
    FlData d;
} FlInstance;

/* Log categories understood by fl_set_debug_logging.  Errors and warnings
 * are always reported; info messages (category logEvents) only while debug
 * logging is on and logEvents (or logAll, or no category at all) is enabled. */
#define FL_CAT_ERROR "logStatusError"
#define FL_CAT_WARNING "logStatusWarning"
#define FL_CAT_EVENTS "logEvents"
#define FL_CAT_ALL "logAll"

/* ---- creation and destruction ---- */

/* Returns NULL (after logging the reason) if the token does not match
 * MODEL_INSTANTIATION_TOKEN, Model Exchange is asked of a model without continuous states, or
 * memory is exhausted. */
WMR_INTERNAL
FlInstance *fl_instantiate(const char *fn, const char *instance_name, const char *token,
                           int model_exchange, int logging_on, FlLogAdapter adapter,
                           void (*importer_logger)(void), void *importer_env,
                           const char *resources, int resources_is_uri);
WMR_INTERNAL
void fl_free(FlInstance *inst);

/* Log without an instance (e.g. when instantiation is refused before any
 * instance exists); uses a temporary instance on the stack. */
WMR_INTERNAL
void fl_log_no_instance(const char *instance_name, FlLogAdapter adapter,
                        void (*importer_logger)(void), void *importer_env,
                        FlStatus status, const char *fmt, ...);

/* ---- logging and state checks (used by the shells too) ---- */

WMR_INTERNAL
void fl_log(FlInstance *inst, FlStatus status, const char *fmt, ...);
WMR_INTERNAL
FlStatus fl_set_debug_logging(const char *fn, FlInstance *inst, int logging_on,
                              size_t n_categories, const char *const categories[]);
/* 1 if inst is not NULL and in one of the states of mask, else logs and returns 0. */
WMR_INTERNAL
int fl_check_state(const char *fn, FlInstance *inst, int mask);
/* Log an error for an unsupported function and return FL_ERROR. */
WMR_INTERNAL
FlStatus fl_unsupported(const char *fn, FlInstance *inst, const char *why);
/* For the typed accessors of types the model does not have: OK if nvr == 0. */
WMR_INTERNAL
FlStatus fl_no_variables_of_type(const char *fn, FlInstance *inst, int mask,
                                 const unsigned int vr[], size_t nvr, const char *type_name);
WMR_INTERNAL
const char *fl_mode_name(int mode);

/* ---- life cycle ---- */

WMR_INTERNAL
FlStatus fl_setup_experiment(const char *fn, FlInstance *inst, int tolerance_defined,
                             double tolerance, double start_time, int stop_time_defined,
                             double stop_time);
WMR_INTERNAL
FlStatus fl_enter_initialization_mode(const char *fn, FlInstance *inst);
WMR_INTERNAL
FlStatus fl_exit_initialization_mode(const char *fn, FlInstance *inst);
WMR_INTERNAL
FlStatus fl_terminate(const char *fn, FlInstance *inst);
WMR_INTERNAL
FlStatus fl_reset(const char *fn, FlInstance *inst);

/* ---- variables (value reference == index in MODEL_VARIABLES) ---- */

WMR_INTERNAL
FlStatus fl_get_real(const char *fn, FlInstance *inst, const unsigned int vr[], size_t nvr,
                     double values[]);
WMR_INTERNAL
FlStatus fl_set_real(const char *fn, FlInstance *inst, const unsigned int vr[], size_t nvr,
                     const double values[]);

/* ---- stepping ---- */

/* *last_successful_time (may be NULL) receives the instance time after the call. */
WMR_INTERNAL
FlStatus fl_do_step(const char *fn, FlInstance *inst, double current_communication_point,
                    double step_size, double *last_successful_time);
WMR_INTERNAL
FlStatus fl_get_time(const char *fn, FlInstance *inst, double *time);

/* ---- Model Exchange (no events: event indicators, discrete states and time events are none) ---- */

WMR_INTERNAL
FlStatus fl_enter_event_mode(const char *fn, FlInstance *inst);
/* The discrete-state iteration converges at once: nothing changes. */
WMR_INTERNAL
FlStatus fl_update_discrete_states(const char *fn, FlInstance *inst);
WMR_INTERNAL
FlStatus fl_enter_continuous_time_mode(const char *fn, FlInstance *inst);
WMR_INTERNAL
FlStatus fl_completed_integrator_step(const char *fn, FlInstance *inst);
WMR_INTERNAL
FlStatus fl_set_time(const char *fn, FlInstance *inst, double time);
/* The continuous state vector x[MODEL_NX]: n must equal MODEL_NX. */
WMR_INTERNAL
FlStatus fl_set_continuous_states(const char *fn, FlInstance *inst, const double x[],
                                  size_t n);
WMR_INTERNAL
FlStatus fl_get_continuous_states(const char *fn, FlInstance *inst, double x[], size_t n);
WMR_INTERNAL
FlStatus fl_get_derivatives(const char *fn, FlInstance *inst, double dx[], size_t n);
WMR_INTERNAL
FlStatus fl_get_nominals(const char *fn, FlInstance *inst, double nominals[], size_t n);
WMR_INTERNAL
FlStatus fl_get_event_indicators(const char *fn, FlInstance *inst, double indicators[],
                                 size_t n);

/* ---- variable dependencies (FMI 3) ---- */

/* The dependencies of the unknown vr, from the generated tables (MODEL_DEPENDENCY_ROWS, written
 * from the same model structure as the model description): in Instantiated and
 * InitializationMode those of the initial unknowns, afterwards those at communication points
 * and in continuous-time mode.  Sets *n; with knowns != NULL also writes n_given (== *n)
 * value references and kinds (numbered as fmi3DependencyKind). */
WMR_INTERNAL
FlStatus fl_variable_dependencies(const char *fn, FlInstance *inst, unsigned int vr, size_t *n,
                                  unsigned int knowns[], int kinds[], size_t n_given);

/* ---- partial derivatives ---- */

/* Directional (adjoint = 0) or adjoint (adjoint = 1) derivative of the unknowns (outputs and
 * state derivatives) with respect to the knowns (continuous states and inputs), from the
 * model core's exact Jacobian at the current x, u, p:
 *   forward: sensitivity[i] = sum_j J[unknown i][known j] * seed[j]  (n_knowns seeds)
 *   adjoint: sensitivity[j] = sum_i seed[i] * J[unknown i][known j]  (n_unknowns seeds) */
WMR_INTERNAL
FlStatus fl_partial_derivative(const char *fn, FlInstance *inst,
                               const unsigned int unknowns[], size_t n_unknowns,
                               const unsigned int knowns[], size_t n_knowns,
                               const double seed[], double sensitivity[],
                               int adjoint);

/* ---- FMU state ---- */

WMR_INTERNAL
FlStatus fl_get_fmu_state(const char *fn, FlInstance *inst, void **state);
WMR_INTERNAL
FlStatus fl_set_fmu_state(const char *fn, FlInstance *inst, const void *state);
WMR_INTERNAL
FlStatus fl_free_fmu_state(const char *fn, FlInstance *inst, void **state);
WMR_INTERNAL
FlStatus fl_serialized_size(const char *fn, FlInstance *inst, const void *state, size_t *size);
WMR_INTERNAL
FlStatus fl_serialize(const char *fn, FlInstance *inst, const void *state,
                      unsigned char *buffer, size_t size);
WMR_INTERNAL
FlStatus fl_deserialize(const char *fn, FlInstance *inst, const unsigned char *buffer,
                        size_t size, void **state);

#endif
