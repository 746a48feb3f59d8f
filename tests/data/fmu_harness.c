/* A minimal FMI co-simulation master for the platform tests: it loads an FMU's shared library
 * (dlopen or LoadLibrary), drives it with a fixed torque sequence and prints every output after
 * every step with 17 digits, so that the same run on linux64, on aarch64 under qemu and on
 * win64 under wine can be compared number by number.
 *
 * usage: fmu_harness LIBRARY FMI_VERSION TOKEN N_STEPS STEP_SIZE VR_TAU_R VR_TAU_L VR_OUT...
 *
 * The torques are plain rational numbers (no libm call) so that every platform gets the same
 * input bits: tau_r = ((7 k) mod 11) / 10 - 0.5, tau_l = ((5 k) mod 13) / 12 - 0.4 N.m.
 */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>

#include "fmi2FunctionTypes.h"
#include "fmi3FunctionTypes.h"

#ifdef _WIN32
#include <windows.h>
static void *open_library(const char *path) { return (void *)LoadLibraryA(path); }
static void *symbol(void *lib, const char *name) {
    return (void *)GetProcAddress((HMODULE)lib, name);
}
#else
#include <dlfcn.h>
static void *open_library(const char *path) { return dlopen(path, RTLD_NOW | RTLD_LOCAL); }
static void *symbol(void *lib, const char *name) { return dlsym(lib, name); }
#endif

#define MAX_OUT 64

static void *lib;

static void *need(const char *name) {
    void *f = symbol(lib, name);
    if (!f) {
        fprintf(stderr, "harness: %s is missing\n", name);
        exit(3);
    }
    return f;
}

static void log_fmi2(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                 fmi2String category, fmi2String message, ...) {
    (void)env;
    (void)name;
    fprintf(stderr, "fmu [%d] %s: %s\n", (int)status, category, message);
}

static void log_fmi3(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category,
                 fmi3String message) {
    (void)env;
    fprintf(stderr, "fmu [%d] %s: %s\n", (int)status, category, message);
}

static void torques(int k, double u[2]) {
    u[0] = (double)((7 * k) % 11) / 10.0 - 0.5;
    u[1] = (double)((5 * k) % 13) / 12.0 - 0.4;
}

static void print_row(double t, const double *y, int ny) {
    printf("%.17g", t);
    for (int i = 0; i < ny; i++) printf(" %.17g", y[i]);
    printf("\n");
}

static int run2(const char *token, int n, double h, const unsigned *vr_in, const unsigned *vr_out,
                int ny) {
    fmi2CallbackFunctions cb = {log_fmi2, calloc, free, NULL, NULL};
    fmi2InstantiateTYPE *instantiate = (fmi2InstantiateTYPE *)need("fmi2Instantiate");
    fmi2SetupExperimentTYPE *setup = (fmi2SetupExperimentTYPE *)need("fmi2SetupExperiment");
    fmi2EnterInitializationModeTYPE *enter =
        (fmi2EnterInitializationModeTYPE *)need("fmi2EnterInitializationMode");
    fmi2ExitInitializationModeTYPE *leave =
        (fmi2ExitInitializationModeTYPE *)need("fmi2ExitInitializationMode");
    fmi2SetRealTYPE *set = (fmi2SetRealTYPE *)need("fmi2SetReal");
    fmi2GetRealTYPE *get = (fmi2GetRealTYPE *)need("fmi2GetReal");
    fmi2DoStepTYPE *step = (fmi2DoStepTYPE *)need("fmi2DoStep");
    fmi2FreeInstanceTYPE *release = (fmi2FreeInstanceTYPE *)need("fmi2FreeInstance");
    fmi2Component c = instantiate("harness", fmi2CoSimulation, token, NULL, &cb, fmi2False,
                                  fmi2False);
    if (!c) return 4;
    if (setup(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) > fmi2Warning) return 5;
    if (enter(c) > fmi2Warning || leave(c) > fmi2Warning) return 5;
    double u[2], y[MAX_OUT];
    for (int k = 0; k < n; k++) {
        torques(k, u);
        if (set(c, vr_in, 2, u) > fmi2Warning) return 6;
        if (step(c, k * h, h, fmi2True) > fmi2Warning) return 7;
        if (get(c, vr_out, (size_t)ny, y) > fmi2Warning) return 8;
        print_row((k + 1) * h, y, ny);
    }
    release(c);
    return 0;
}

static int run3(const char *token, int n, double h, const unsigned *vr_in, const unsigned *vr_out,
                int ny) {
    fmi3InstantiateCoSimulationTYPE *instantiate =
        (fmi3InstantiateCoSimulationTYPE *)need("fmi3InstantiateCoSimulation");
    fmi3EnterInitializationModeTYPE *enter =
        (fmi3EnterInitializationModeTYPE *)need("fmi3EnterInitializationMode");
    fmi3ExitInitializationModeTYPE *leave =
        (fmi3ExitInitializationModeTYPE *)need("fmi3ExitInitializationMode");
    fmi3SetFloat64TYPE *set = (fmi3SetFloat64TYPE *)need("fmi3SetFloat64");
    fmi3GetFloat64TYPE *get = (fmi3GetFloat64TYPE *)need("fmi3GetFloat64");
    fmi3DoStepTYPE *step = (fmi3DoStepTYPE *)need("fmi3DoStep");
    fmi3FreeInstanceTYPE *release = (fmi3FreeInstanceTYPE *)need("fmi3FreeInstance");
    fmi3Instance c = instantiate("harness", token, NULL, fmi3False, fmi3False, fmi3False,
                                 fmi3False, NULL, 0, NULL, log_fmi3, NULL);
    if (!c) return 4;
    if (enter(c, fmi3False, 0.0, 0.0, fmi3False, 0.0) > fmi3Warning) return 5;
    if (leave(c) > fmi3Warning) return 5;
    double u[2], y[MAX_OUT];
    fmi3Boolean event, terminate, early;
    fmi3Float64 last;
    for (int k = 0; k < n; k++) {
        torques(k, u);
        if (set(c, vr_in, 2, u, 2) > fmi3Warning) return 6;
        if (step(c, k * h, h, fmi3True, &event, &terminate, &early, &last) > fmi3Warning)
            return 7;
        if (get(c, vr_out, (size_t)ny, y, (size_t)ny) > fmi3Warning) return 8;
        print_row((k + 1) * h, y, ny);
    }
    release(c);
    return 0;
}

int main(int argc, char **argv) {
    if (argc < 9 || argc - 8 > MAX_OUT) {
        fprintf(stderr, "usage: %s LIBRARY FMI_VERSION TOKEN N_STEPS STEP_SIZE VR_TAU_R VR_TAU_L "
                        "VR_OUT...\n", argv[0]);
        return 2;
    }
    lib = open_library(argv[1]);
    if (!lib) {
        fprintf(stderr, "harness: cannot load %s\n", argv[1]);
        return 3;
    }
    int version = atoi(argv[2]);
    int n = atoi(argv[4]);
    double h = atof(argv[5]);
    unsigned vr_in[2] = {(unsigned)strtoul(argv[6], NULL, 10),
                         (unsigned)strtoul(argv[7], NULL, 10)};
    unsigned vr_out[MAX_OUT];
    int ny = argc - 8;
    for (int i = 0; i < ny; i++) vr_out[i] = (unsigned)strtoul(argv[8 + i], NULL, 10);
    return version == 2 ? run2(argv[3], n, h, vr_in, vr_out, ny)
                        : run3(argv[3], n, h, vr_in, vr_out, ny);
}
