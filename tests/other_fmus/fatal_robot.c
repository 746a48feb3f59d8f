/* A hostile FMI 2.0 co-simulation robot for tests/test_hostile_inputs.py.
 *
 * It has our interface names (tau_r, tau_l in; x, y, theta, v, omega, omega_r, omega_l out;
 * x0, y0, theta0 parameters) and a crude unicycle inside.  A non-finite input makes it return
 * fmi2Fatal, as a foreign FMU may; from then on ANY call (fmi2Terminate, fmi2FreeInstance,
 * fmi2Reset, ...), which FMI 2.0 (section 2.1.3) forbids after fmi2Fatal, crashes the process
 * with SIGSEGV, as an FMU whose memory is corrupted would.  Stubs take any arguments (empty
 * parameter lists): only the calls the importer makes matter. */
#include <math.h>
#include <signal.h>
#include <stddef.h>

#define N_VARS 12 /* 0,1 tau_r,tau_l; 2..8 outputs; 9..11 x0,y0,theta0 */
static double val[N_VARS];
static int fatal = 0;
static int instance = 1;

static int alive(void) {
    if (fatal) raise(SIGSEGV); /* called after fmi2Fatal: the standard allows no call */
    return 0;
}

const char *fmi2GetTypesPlatform(void) { return "default"; }
const char *fmi2GetVersion(void) { return "2.0"; }
void *fmi2Instantiate() { return &instance; }
void fmi2FreeInstance() { alive(); }
int fmi2SetupExperiment() { return alive(); }
int fmi2EnterInitializationMode() { return alive(); }
int fmi2ExitInitializationMode() {
    alive();
    val[2] = val[9]; val[3] = val[10]; val[4] = val[11];
    return 0;
}
int fmi2Terminate() { return alive(); }
int fmi2Reset() { return alive(); }
int fmi2SetReal(void *c, const unsigned *vr, size_t n, const double *v) {
    alive();
    for (size_t i = 0; i < n; i++) {
        if (!isfinite(v[i])) { fatal = 1; return 4; /* fmi2Fatal */ }
        if (vr[i] < N_VARS) val[vr[i]] = v[i];
    }
    return 0;
}
int fmi2GetReal(void *c, const unsigned *vr, size_t n, double *v) {
    alive();
    for (size_t i = 0; i < n; i++) v[i] = vr[i] < N_VARS ? val[vr[i]] : 0.0;
    return 0;
}
int fmi2DoStep(void *c, double t, double h, int no_prior) {
    alive();
    double *x = val + 2; /* x y theta v omega omega_r omega_l */
    x[3] += h * (val[0] + val[1]) / 25.0;
    x[4] += h * (val[0] - val[1]) / 2.0;
    x[0] += h * x[3] * cos(x[2]);
    x[1] += h * x[3] * sin(x[2]);
    x[2] += h * x[4];
    x[5] = (x[3] + 0.3 * x[4]) / 0.15;
    x[6] = (x[3] - 0.3 * x[4]) / 0.15;
    return 0;
}
#define STUB(name) int name() { return alive(); }
STUB(fmi2SetDebugLogging) STUB(fmi2GetInteger) STUB(fmi2GetBoolean) STUB(fmi2GetString)
STUB(fmi2SetInteger) STUB(fmi2SetBoolean) STUB(fmi2SetString) STUB(fmi2GetFMUstate)
STUB(fmi2SetFMUstate) STUB(fmi2FreeFMUstate) STUB(fmi2SerializedFMUstateSize)
STUB(fmi2SerializeFMUstate) STUB(fmi2DeSerializeFMUstate) STUB(fmi2GetDirectionalDerivative)
STUB(fmi2SetRealInputDerivatives) STUB(fmi2GetRealOutputDerivatives) STUB(fmi2CancelStep)
STUB(fmi2GetStatus) STUB(fmi2GetRealStatus) STUB(fmi2GetIntegerStatus)
STUB(fmi2GetBooleanStatus) STUB(fmi2GetStringStatus)
