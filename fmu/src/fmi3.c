/*
 * fmi3.c: FMI 3.0 Co-Simulation and Model Exchange entry points, thin shells over
 * fmi_layer.c.
 *
 * Every function the standard requires an FMU binary to export is defined;
 * those of Scheduled Execution, clocks and configuration mode log why and
 * return fmi3Error (or NULL for the instantiate function).  With
 * -fvisibility=hidden only the fmi3* functions (declared FMI3_Export by
 * fmi3Functions.h) are visible; FMI3_FUNCTION_PREFIX renames them.
 */
#include <stddef.h>
#include <string.h>

#include "fmi3Functions.h"
#include "fmi_layer.h"

#define INST ((FlInstance *)instance)

#define UNSUPPORTED(name, why) ((fmi3Status)fl_unsupported(#name, INST, why))

static void log_adapter(const FlInstance *inst, FlStatus status, const char *category,
                        const char *message) {
    fmi3LogMessageCallback logger = (fmi3LogMessageCallback)inst->importer_logger;
    if (!logger) return;
    logger((fmi3InstanceEnvironment)inst->importer_env, (fmi3Status)status, category, message);
}

/* all variables are scalars: nValues must equal nValueReferences */
static int check_n_values(const char *fn, FlInstance *inst, size_t nvr, size_t n_values) {
    if (!inst) return 0;
    if (n_values != nvr) {
        fl_log(inst, FL_ERROR, "%s: nValues = %lu, expected %lu (all variables are scalars)", fn,
               (unsigned long)n_values, (unsigned long)nvr);
        return 0;
    }
    return 1;
}

/* ---- inquire version numbers and set debug logging ---- */

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    return (fmi3Status)fl_set_debug_logging("fmi3SetDebugLogging", INST, loggingOn, nCategories,
                                            categories);
}

/* ---- creation and destruction ---- */

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)visible;
    return (fmi3Instance)fl_instantiate("fmi3InstantiateModelExchange", instanceName,
                                        instantiationToken, 1, loggingOn, log_adapter,
                                        (void (*)(void))logMessage, instanceEnvironment,
                                        resourcePath, 0);
}

fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference requiredIntermediateVariables[],
    size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate) {
    /* early return is never used (doStep always completes), intermediate
     * updates are never made */
    (void)visible; (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables; (void)nRequiredIntermediateVariables;
    (void)intermediateUpdate;
    if (eventModeUsed) {
        fl_log_no_instance(instanceName, log_adapter, (void (*)(void))logMessage,
                           instanceEnvironment, FL_ERROR,
                           "fmi3InstantiateCoSimulation: eventModeUsed = true is not supported "
                           "(hasEventMode is false)");
        return NULL;
    }
    return (fmi3Instance)fl_instantiate("fmi3InstantiateCoSimulation", instanceName,
                                        instantiationToken, 0, loggingOn, log_adapter,
                                        (void (*)(void))logMessage, instanceEnvironment,
                                        resourcePath, 0);
}

fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
    fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instantiationToken; (void)resourcePath; (void)visible; (void)loggingOn;
    (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    fl_log_no_instance(instanceName, log_adapter, (void (*)(void))logMessage, instanceEnvironment,
                       FL_ERROR,
                       "fmi3InstantiateScheduledExecution: this FMU supports Co-Simulation and "
                       "Model Exchange only");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) { fl_free(INST); }

/* ---- initialisation, termination, reset ---- */

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    const char *fn = "fmi3EnterInitializationMode";
    FlStatus st = fl_setup_experiment(fn, INST, toleranceDefined, tolerance, startTime,
                                      stopTimeDefined, stopTime);
    if (st > FL_WARNING) return (fmi3Status)st;
    return (fmi3Status)fl_enter_initialization_mode(fn, INST);
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    return (fmi3Status)fl_exit_initialization_mode("fmi3ExitInitializationMode", INST);
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    /* Model Exchange only: a Co-Simulation instance has hasEventMode = false */
    return (fmi3Status)fl_enter_event_mode("fmi3EnterEventMode", INST);
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    return (fmi3Status)fl_terminate("fmi3Terminate", INST);
}

fmi3Status fmi3Reset(fmi3Instance instance) { return (fmi3Status)fl_reset("fmi3Reset", INST); }

/* ---- getting and setting variable values ---- */

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float64 values[], size_t nValues) {
    const char *fn = "fmi3GetFloat64";
    if (!fl_check_state(fn, INST, FL_GET_MASK)) return fmi3Error;
    if (!check_n_values(fn, INST, nValueReferences, nValues)) return fmi3Error;
    return (fmi3Status)fl_get_real(fn, INST, valueReferences, nValueReferences, values);
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float64 values[], size_t nValues) {
    const char *fn = "fmi3SetFloat64";
    if (!fl_check_state(fn, INST, FL_SET_MASK)) return fmi3Error;
    if (!check_n_values(fn, INST, nValueReferences, nValues)) return fmi3Error;
    return (fmi3Status)fl_set_real(fn, INST, valueReferences, nValueReferences, values);
}

/* The model has Float64 variables only. */
#define NO_VARIABLES_GET(T)                                                                   \
    fmi3Status fmi3Get##T(fmi3Instance instance, const fmi3ValueReference valueReferences[],   \
                          size_t nValueReferences, fmi3##T values[], size_t nValues) {        \
        (void)values; (void)nValues;                                                          \
        return (fmi3Status)fl_no_variables_of_type("fmi3Get" #T, INST, FL_GET_MASK,              \
                                                   valueReferences, nValueReferences, #T);   \
    }
#define NO_VARIABLES_SET(T)                                                                   \
    fmi3Status fmi3Set##T(fmi3Instance instance, const fmi3ValueReference valueReferences[],   \
                          size_t nValueReferences, const fmi3##T values[], size_t nValues) {  \
        (void)values; (void)nValues;                                                          \
        return (fmi3Status)fl_no_variables_of_type("fmi3Set" #T, INST, FL_SET_MASK,              \
                                                   valueReferences, nValueReferences, #T);   \
    }

NO_VARIABLES_GET(Float32)
NO_VARIABLES_GET(Int8)
NO_VARIABLES_GET(UInt8)
NO_VARIABLES_GET(Int16)
NO_VARIABLES_GET(UInt16)
NO_VARIABLES_GET(Int32)
NO_VARIABLES_GET(UInt32)
NO_VARIABLES_GET(Int64)
NO_VARIABLES_GET(UInt64)
NO_VARIABLES_GET(Boolean)
NO_VARIABLES_GET(String)

NO_VARIABLES_SET(Float32)
NO_VARIABLES_SET(Int8)
NO_VARIABLES_SET(UInt8)
NO_VARIABLES_SET(Int16)
NO_VARIABLES_SET(UInt16)
NO_VARIABLES_SET(Int32)
NO_VARIABLES_SET(UInt32)
NO_VARIABLES_SET(Int64)
NO_VARIABLES_SET(UInt64)
NO_VARIABLES_SET(Boolean)
NO_VARIABLES_SET(String)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, size_t valueSizes[], fmi3Binary values[],
                         size_t nValues) {
    (void)valueSizes; (void)values; (void)nValues;
    return (fmi3Status)fl_no_variables_of_type("fmi3GetBinary", INST, FL_GET_MASK, valueReferences,
                                               nValueReferences, "Binary");
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, const size_t valueSizes[],
                         const fmi3Binary values[], size_t nValues) {
    (void)valueSizes; (void)values; (void)nValues;
    return (fmi3Status)fl_no_variables_of_type("fmi3SetBinary", INST, FL_SET_MASK, valueReferences,
                                               nValueReferences, "Binary");
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, fmi3Clock values[]) {
    (void)values;
    return (fmi3Status)fl_no_variables_of_type("fmi3GetClock", INST, FL_ANY_STATE,
                                               valueReferences, nValueReferences, "Clock");
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, const fmi3Clock values[]) {
    (void)values;
    return (fmi3Status)fl_no_variables_of_type("fmi3SetClock", INST, FL_ANY_STATE,
                                               valueReferences, nValueReferences, "Clock");
}

/* ---- variable dependencies ---- */

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance,
                                               fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    return (fmi3Status)fl_variable_dependencies("fmi3GetNumberOfVariableDependencies", INST,
                                                valueReference, nDependencies, NULL, NULL, 0);
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[],
                                       fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies) {
    const char *fn = "fmi3GetVariableDependencies";
    unsigned int knowns[MODEL_NV + 1];
    int kinds[MODEL_NV + 1];
    size_t k, n = 0;
    FlStatus st;
    if (!fl_check_state(fn, INST, FL_ANY_STATE)) return fmi3Error;
    if (nDependencies > 0 && (!elementIndicesOfDependent || !independents ||
                              !elementIndicesOfIndependents || !dependencyKinds)) {
        fl_log(INST, FL_ERROR, "%s: an array argument is NULL", fn);
        return fmi3Error;
    }
    if (nDependencies > (size_t)MODEL_NV) {
        fl_log(INST, FL_ERROR, "%s: nDependencies = %lu, the model has %d variables", fn,
               (unsigned long)nDependencies, MODEL_NV);
        return fmi3Error;
    }
    st = fl_variable_dependencies(fn, INST, dependent, &n, knowns, kinds, nDependencies);
    if (st != FL_OK) return (fmi3Status)st;
    for (k = 0; k < n; k++) {
        elementIndicesOfDependent[k] = 0; /* every variable is a scalar */
        independents[k] = knowns[k];
        elementIndicesOfIndependents[k] = 0;
        dependencyKinds[k] = (fmi3DependencyKind)kinds[k];
    }
    return fmi3OK;
}

/* ---- FMU state ---- */

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    return (fmi3Status)fl_get_fmu_state("fmi3GetFMUState", INST, FMUState);
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    return (fmi3Status)fl_set_fmu_state("fmi3SetFMUState", INST, FMUState);
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    return (fmi3Status)fl_free_fmu_state("fmi3FreeFMUState", INST, FMUState);
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState,
                                      size_t *size) {
    return (fmi3Status)fl_serialized_size("fmi3SerializedFMUStateSize", INST, FMUState, size);
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState,
                                 fmi3Byte serializedState[], size_t size) {
    return (fmi3Status)fl_serialize("fmi3SerializeFMUState", INST, FMUState, serializedState,
                                    size);
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[],
                                   size_t size, fmi3FMUState *FMUState) {
    return (fmi3Status)fl_deserialize("fmi3DeserializeFMUState", INST, serializedState, size,
                                      FMUState);
}

/* ---- partial derivatives ---- */

/* all variables are scalars: nSeed and nSensitivity follow from the numbers of
 * unknowns and knowns */
static fmi3Status partial_derivative(const char *fn, FlInstance *inst,
                                     const fmi3ValueReference unknowns[], size_t nUnknowns,
                                     const fmi3ValueReference knowns[], size_t nKnowns,
                                     const fmi3Float64 seed[], size_t nSeed,
                                     fmi3Float64 sensitivity[], size_t nSensitivity,
                                     int adjoint) {
    size_t n_seed = adjoint ? nUnknowns : nKnowns, n_sens = adjoint ? nKnowns : nUnknowns;
    if (!fl_check_state(fn, inst, FL_ANY_STATE)) return fmi3Error;
    if (nSeed != n_seed || nSensitivity != n_sens) {
        fl_log(inst, FL_ERROR, "%s: nSeed = %lu and nSensitivity = %lu, expected %lu and %lu "
                               "(all variables are scalars)",
               fn, (unsigned long)nSeed, (unsigned long)nSensitivity, (unsigned long)n_seed,
               (unsigned long)n_sens);
        return fmi3Error;
    }
    return (fmi3Status)fl_partial_derivative(fn, inst, unknowns, nUnknowns, knowns, nKnowns, seed,
                                             sensitivity, adjoint);
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[],
                                        size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                        fmi3Float64 sensitivity[], size_t nSensitivity) {
    return partial_derivative("fmi3GetDirectionalDerivative", INST, unknowns, nUnknowns, knowns,
                              nKnowns, seed, nSeed, sensitivity, nSensitivity, 0);
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                    size_t nUnknowns, const fmi3ValueReference knowns[],
                                    size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                    fmi3Float64 sensitivity[], size_t nSensitivity) {
    return partial_derivative("fmi3GetAdjointDerivative", INST, unknowns, nUnknowns, knowns,
                              nKnowns, seed, nSeed, sensitivity, nSensitivity, 1);
}

/* ---- configuration mode, clocks ---- */

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    return UNSUPPORTED(fmi3EnterConfigurationMode, "the model has no structural parameters");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    return UNSUPPORTED(fmi3ExitConfigurationMode, "the model has no structural parameters");
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, fmi3Float64 intervals[],
                                  fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences; (void)nValueReferences; (void)intervals; (void)qualifiers;
    return UNSUPPORTED(fmi3GetIntervalDecimal, "the model has no clocks");
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance instance,
                                   const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, fmi3UInt64 counters[],
                                   fmi3UInt64 resolutions[], fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    (void)qualifiers;
    return UNSUPPORTED(fmi3GetIntervalFraction, "the model has no clocks");
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, fmi3Float64 shifts[]) {
    (void)valueReferences; (void)nValueReferences; (void)shifts;
    return UNSUPPORTED(fmi3GetShiftDecimal, "the model has no clocks");
}

fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, fmi3UInt64 counters[],
                                fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return UNSUPPORTED(fmi3GetShiftFraction, "the model has no clocks");
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, const fmi3Float64 intervals[]) {
    (void)valueReferences; (void)nValueReferences; (void)intervals;
    return UNSUPPORTED(fmi3SetIntervalDecimal, "the model has no clocks");
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance instance,
                                   const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, const fmi3UInt64 counters[],
                                   const fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return UNSUPPORTED(fmi3SetIntervalFraction, "the model has no clocks");
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, const fmi3Float64 shifts[]) {
    (void)valueReferences; (void)nValueReferences; (void)shifts;
    return UNSUPPORTED(fmi3SetShiftDecimal, "the model has no clocks");
}

fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, const fmi3UInt64 counters[],
                                const fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return UNSUPPORTED(fmi3SetShiftFraction, "the model has no clocks");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    return UNSUPPORTED(fmi3EvaluateDiscreteStates, "the model has no discrete states");
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    const char *fn = "fmi3UpdateDiscreteStates";
    FlStatus st = fl_update_discrete_states(fn, INST);
    if (st != FL_OK) return (fmi3Status)st;
    if (!discreteStatesNeedUpdate || !terminateSimulation || !nominalsOfContinuousStatesChanged ||
        !valuesOfContinuousStatesChanged || !nextEventTimeDefined || !nextEventTime)
        return UNSUPPORTED(fmi3UpdateDiscreteStates, "an output argument pointer is NULL");
    /* no events: the iteration has converged, nothing changed, no time event ahead */
    *discreteStatesNeedUpdate = fmi3False;
    *terminateSimulation = fmi3False;
    *nominalsOfContinuousStatesChanged = fmi3False;
    *valuesOfContinuousStatesChanged = fmi3False;
    *nextEventTimeDefined = fmi3False;
    *nextEventTime = 0.0;
    return fmi3OK;
}

/* ---- Model Exchange ---- */

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    return (fmi3Status)fl_enter_continuous_time_mode("fmi3EnterContinuousTimeMode", INST);
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance,
                                       fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode,
                                       fmi3Boolean *terminateSimulation) {
    FlStatus st;
    (void)noSetFMUStatePriorToCurrentPoint;
    st = fl_completed_integrator_step("fmi3CompletedIntegratorStep", INST);
    if (st != FL_OK) return (fmi3Status)st;
    if (!enterEventMode || !terminateSimulation)
        return UNSUPPORTED(fmi3CompletedIntegratorStep, "an output argument pointer is NULL");
    *enterEventMode = fmi3False;
    *terminateSimulation = fmi3False;
    return fmi3OK;
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    return (fmi3Status)fl_set_time("fmi3SetTime", INST, time);
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    return (fmi3Status)fl_set_continuous_states("fmi3SetContinuousStates", INST, continuousStates,
                                                nContinuousStates);
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    return (fmi3Status)fl_get_derivatives("fmi3GetContinuousStateDerivatives", INST, derivatives,
                                          nContinuousStates);
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[],
                                  size_t nEventIndicators) {
    return (fmi3Status)fl_get_event_indicators("fmi3GetEventIndicators", INST, eventIndicators,
                                               nEventIndicators);
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    return (fmi3Status)fl_get_continuous_states("fmi3GetContinuousStates", INST, continuousStates,
                                                nContinuousStates);
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    return (fmi3Status)fl_get_nominals("fmi3GetNominalsOfContinuousStates", INST, nominals,
                                       nContinuousStates);
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    if (!fl_check_state("fmi3GetNumberOfEventIndicators", INST, FL_ANY_STATE)) return fmi3Error;
    if (!nEventIndicators)
        return UNSUPPORTED(fmi3GetNumberOfEventIndicators, "nEventIndicators is NULL");
    *nEventIndicators = 0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    if (!fl_check_state("fmi3GetNumberOfContinuousStates", INST, FL_ANY_STATE)) return fmi3Error;
    if (!nContinuousStates)
        return UNSUPPORTED(fmi3GetNumberOfContinuousStates, "nContinuousStates is NULL");
    *nContinuousStates = MODEL_NX;
    return fmi3OK;
}

/* ---- Co-Simulation ---- */

fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    /* only allowed in Event Mode, which this FMU never enters: after
     * fmi3ExitInitializationMode the instance is already in Step Mode */
    const char *fn = "fmi3EnterStepMode";
    if (!INST) return fmi3Error;
    fl_log(INST, FL_ERROR, "%s: expected state EventMode, was %s (event mode is not supported; "
                           "the FMU is in StepMode after fmi3ExitInitializationMode)",
           fn, fl_mode_name(INST->d.mode));
    return fmi3Error;
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance,
                                    const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Int32 orders[],
                                    fmi3Float64 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)orders; (void)values; (void)nValues;
    return UNSUPPORTED(fmi3GetOutputDerivatives, "maxOutputDerivativeOrder is 0");
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    const char *fn = "fmi3DoStep";
    double t_last;
    FlStatus st;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!INST) return fmi3Error;
    if (!eventHandlingNeeded || !terminateSimulation || !earlyReturn || !lastSuccessfulTime) {
        fl_log(INST, FL_ERROR, "%s: an output argument pointer is NULL", fn);
        return fmi3Error;
    }
    *eventHandlingNeeded = fmi3False;
    *terminateSimulation = fmi3False;
    *earlyReturn = fmi3False;
    st = fl_do_step(fn, INST, currentCommunicationPoint, communicationStepSize, &t_last);
    *lastSuccessfulTime = t_last;
    /* a sample of this step or before ended the run: ask the importer to stop (it then calls
     * fmi3Terminate); a master that steps on gets the outputs held at rest */
    if (st == FL_OK && INST->d.run_over) *terminateSimulation = fmi3True;
    return (fmi3Status)st;
}

/* ---- Scheduled Execution (not supported) ---- */

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference; (void)activationTime;
    return UNSUPPORTED(fmi3ActivateModelPartition, "Scheduled Execution is not supported");
}
