/*
 * fmi2.c: FMI 2.0 Co-Simulation and Model Exchange entry points, thin shells over
 * fmi_layer.c.
 *
 * Binary FMU: the functions are exported without a prefix.  With
 * -fvisibility=hidden only the fmi2* functions (declared FMI2_Export by
 * fmi2Functions.h) are visible outside the shared library; compiled through the
 * unity translation unit everything else is static anyway, and FMI2_FUNCTION_PREFIX
 * renames the fmi2* functions for static linking.
 */
#include <stddef.h>
#include <string.h>

#include "fmi2Functions.h"
#include "fmi_layer.h"

#if defined(FMI2_FUNCTION_PREFIX)
/* The standard's fmi2Functions.h prefixes the names through fmi2FullName; some copies of it
 * (fmpy's) define fmi2FullName(name) as name.  The function-name macros expand fmi2FullName
 * where they are used, so redefining it here prefixes the definitions below either way. */
#undef fmi2FullName
#define WMR_PASTE(a, b) a##b
#define WMR_PASTE2(a, b) WMR_PASTE(a, b)
#define fmi2FullName(name) WMR_PASTE2(FMI2_FUNCTION_PREFIX, name)
#endif

#define INST ((FlInstance *)c)

/* Version-specific log adapter.  The FMI 2 logger is printf-like: the
 * message is passed as the format string, so '%' is escaped as "%%". */
static void log_adapter(const FlInstance *inst, FlStatus status, const char *category,
                        const char *message) {
    char buf[2048];
    size_t i, j = 0;
    fmi2CallbackLogger logger = (fmi2CallbackLogger)inst->importer_logger;
    if (!logger) return;
    for (i = 0; message[i] && j + 2 < sizeof(buf); i++) {
        if (message[i] == '%') buf[j++] = '%';
        buf[j++] = message[i];
    }
    buf[j] = '\0';
    logger((fmi2ComponentEnvironment)inst->importer_env, inst->name, (fmi2Status)status,
           category, buf);
}

/* ---- common functions ---- */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    return (fmi2Status)fl_set_debug_logging("fmi2SetDebugLogging", INST, loggingOn, nCategories,
                                            categories);
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    void (*logger)(void);
    void *env;
    (void)visible;
    if (!functions) return NULL;
    logger = (void (*)(void))functions->logger;
    env = functions->componentEnvironment;
    if (fmuType != fmi2CoSimulation && fmuType != fmi2ModelExchange) {
        fl_log_no_instance(instanceName, log_adapter, logger, env, FL_ERROR,
                           "fmi2Instantiate: fmuType = %d is neither fmi2ModelExchange nor "
                           "fmi2CoSimulation", (int)fmuType);
        return NULL;
    }
    return (fmi2Component)fl_instantiate("fmi2Instantiate", instanceName, fmuGUID,
                                         fmuType == fmi2ModelExchange, loggingOn, log_adapter,
                                         logger, env, fmuResourceLocation, 1);
}

void fmi2FreeInstance(fmi2Component c) { fl_free(INST); }

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    return (fmi2Status)fl_setup_experiment("fmi2SetupExperiment", INST, toleranceDefined,
                                           tolerance, startTime, stopTimeDefined, stopTime);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    return (fmi2Status)fl_enter_initialization_mode("fmi2EnterInitializationMode", INST);
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    return (fmi2Status)fl_exit_initialization_mode("fmi2ExitInitializationMode", INST);
}

fmi2Status fmi2Terminate(fmi2Component c) {
    return (fmi2Status)fl_terminate("fmi2Terminate", INST);
}

fmi2Status fmi2Reset(fmi2Component c) { return (fmi2Status)fl_reset("fmi2Reset", INST); }

/* ---- getting and setting variable values ---- */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    return (fmi2Status)fl_get_real("fmi2GetReal", INST, vr, nvr, value);
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    (void)value;
    return (fmi2Status)fl_no_variables_of_type("fmi2GetInteger", INST, FL_GET_MASK, vr, nvr,
                                               "Integer");
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) {
    (void)value;
    return (fmi2Status)fl_no_variables_of_type("fmi2GetBoolean", INST, FL_GET_MASK, vr, nvr,
                                               "Boolean");
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    (void)value;
    return (fmi2Status)fl_no_variables_of_type("fmi2GetString", INST, FL_GET_MASK, vr, nvr,
                                               "String");
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    return (fmi2Status)fl_set_real("fmi2SetReal", INST, vr, nvr, value);
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    (void)value;
    return (fmi2Status)fl_no_variables_of_type("fmi2SetInteger", INST, FL_SET_MASK, vr, nvr,
                                               "Integer");
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    (void)value;
    return (fmi2Status)fl_no_variables_of_type("fmi2SetBoolean", INST, FL_SET_MASK, vr, nvr,
                                               "Boolean");
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    (void)value;
    return (fmi2Status)fl_no_variables_of_type("fmi2SetString", INST, FL_SET_MASK, vr, nvr,
                                               "String");
}

/* ---- FMU state ---- */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    return (fmi2Status)fl_get_fmu_state("fmi2GetFMUstate", INST, FMUstate);
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    return (fmi2Status)fl_set_fmu_state("fmi2SetFMUstate", INST, FMUstate);
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    return (fmi2Status)fl_free_fmu_state("fmi2FreeFMUstate", INST, FMUstate);
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    return (fmi2Status)fl_serialized_size("fmi2SerializedFMUstateSize", INST, FMUstate, size);
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate,
                                 fmi2Byte serializedState[], size_t size) {
    return (fmi2Status)fl_serialize("fmi2SerializeFMUstate", INST, FMUstate,
                                    (unsigned char *)serializedState, size);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[],
                                   size_t size, fmi2FMUstate *FMUstate) {
    return (fmi2Status)fl_deserialize("fmi2DeSerializeFMUstate", INST,
                                      (const unsigned char *)serializedState, size, FMUstate);
}

/* ---- derivatives ---- */

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    return (fmi2Status)fl_partial_derivative("fmi2GetDirectionalDerivative", INST, vUnknown_ref,
                                             nUnknown, vKnown_ref, nKnown, dvKnown, dvUnknown,
                                             0);
}

/* ---- Model Exchange ---- */

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    return (fmi2Status)fl_enter_event_mode("fmi2EnterEventMode", INST);
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo) {
    const char *fn = "fmi2NewDiscreteStates";
    FlStatus st = fl_update_discrete_states(fn, INST);
    if (st != FL_OK) return (fmi2Status)st;
    if (!eventInfo) return (fmi2Status)fl_unsupported(fn, INST, "eventInfo is NULL");
    /* no events: the iteration has converged, nothing changed, no time event ahead */
    eventInfo->newDiscreteStatesNeeded = fmi2False;
    eventInfo->terminateSimulation = fmi2False;
    eventInfo->nominalsOfContinuousStatesChanged = fmi2False;
    eventInfo->valuesOfContinuousStatesChanged = fmi2False;
    eventInfo->nextEventTimeDefined = fmi2False;
    eventInfo->nextEventTime = 0.0;
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    return (fmi2Status)fl_enter_continuous_time_mode("fmi2EnterContinuousTimeMode", INST);
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c,
                                       fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode,
                                       fmi2Boolean *terminateSimulation) {
    const char *fn = "fmi2CompletedIntegratorStep";
    FlStatus st;
    (void)noSetFMUStatePriorToCurrentPoint;
    st = fl_completed_integrator_step(fn, INST);
    if (st != FL_OK) return (fmi2Status)st;
    if (!enterEventMode || !terminateSimulation)
        return (fmi2Status)fl_unsupported(fn, INST, "an output argument pointer is NULL");
    *enterEventMode = fmi2False;
    *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    return (fmi2Status)fl_set_time("fmi2SetTime", INST, time);
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    return (fmi2Status)fl_set_continuous_states("fmi2SetContinuousStates", INST, x, nx);
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    return (fmi2Status)fl_get_derivatives("fmi2GetDerivatives", INST, derivatives, nx);
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    return (fmi2Status)fl_get_event_indicators("fmi2GetEventIndicators", INST, eventIndicators,
                                               ni);
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    return (fmi2Status)fl_get_continuous_states("fmi2GetContinuousStates", INST, x, nx);
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    return (fmi2Status)fl_get_nominals("fmi2GetNominalsOfContinuousStates", INST, x_nominal, nx);
}

/* ---- co-simulation ---- */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                       size_t nvr, const fmi2Integer order[],
                                       const fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return (fmi2Status)fl_unsupported("fmi2SetRealInputDerivatives", INST,
                                      "canInterpolateInputs is false");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                        size_t nvr, const fmi2Integer order[],
                                        fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return (fmi2Status)fl_unsupported("fmi2GetRealOutputDerivatives", INST,
                                      "maxOutputDerivativeOrder is 0");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    (void)noSetFMUStatePriorToCurrentPoint;
    /* FMI 2.0.4 asks to stop only through fmi2Discard (then fmi2GetBooleanStatus(fmi2Terminated)
     * true).  libcosim fails the run on it and fmpy raises (measured, docs/ssp.md): the step
     * returns OK, fmi2Terminated says the run is over, and the outputs hold the robot still. */
    return (fmi2Status)fl_do_step("fmi2DoStep", INST, currentCommunicationPoint,
                                  communicationStepSize, NULL);
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    return (fmi2Status)fl_unsupported("fmi2CancelStep", INST,
                                      "fmi2DoStep is synchronous and never returns fmi2Pending");
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)s; (void)value;
    return (fmi2Status)fl_unsupported("fmi2GetStatus", INST,
                                      "fmi2DoStep is synchronous and never returns fmi2Pending");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    if (s != fmi2LastSuccessfulTime)
        return (fmi2Status)fl_unsupported("fmi2GetRealStatus", INST,
                                          "only fmi2LastSuccessfulTime is available");
    return (fmi2Status)fl_get_time("fmi2GetRealStatus", INST, value);
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s; (void)value;
    return (fmi2Status)fl_unsupported("fmi2GetIntegerStatus", INST,
                                      "no integer status is defined");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    if (s != fmi2Terminated)
        return (fmi2Status)fl_unsupported("fmi2GetBooleanStatus", INST,
                                          "only fmi2Terminated is available");
    if (!fl_check_state("fmi2GetBooleanStatus", INST, FL_ANY_STATE)) return fmi2Error;
    if (!value) return (fmi2Status)fl_unsupported("fmi2GetBooleanStatus", INST, "value is NULL");
    *value = INST->d.run_over ? fmi2True : fmi2False; /* a sample ended the run */
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)s; (void)value;
    return (fmi2Status)fl_unsupported("fmi2GetStringStatus", INST,
                                      "fmi2DoStep is synchronous and never returns fmi2Pending");
}
