/* The C floor of the closed loop: the robot FMU and the controller FMU (the paper's stabiliser
 * and wheel servos in C) driven from C through their FMI 3 entry points, no log, no Python.
 * benchmarks/loop_vs_c_floor.py compiles it with the system cc and feeds it on stdin:
 *
 *   ROBOT_LIB ROBOT_TOKEN CTRL_LIB CTRL_TOKEN
 *   H N_MAX_LONG N_MAX_SHORT REPEATS
 *   NP_ROBOT (VR VALUE)...      parameters and start of the robot
 *   NP_CTRL (VR VALUE)...       parameters of the controller
 *   VR_TAU_R VR_TAU_L           robot inputs
 *   12 VR...                    robot outputs, in wmr.core.plant.OUTPUT_NAMES order
 *   7 VR...                     controller inputs, in controller_interface.INPUTS order
 *   NY VR... I_TAU_R I_TAU_L I_CONVERGED   controller outputs and where the torques are
 *
 * Per step exactly the calls of `wmr run --controller-fmu`: the controller's convergence
 * test (set, get), its sample (set, get, doStep), the robot's step (set, doStep, get).  For
 * each repetition it prints "steps wall cpu" of the long run, then of the short one: two runs of
 * different length (a run that stops at N_MAX_SHORT), each timed from the first step to the
 * last (wall and CPU seconds), instantiation and initialisation excluded.
 */
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "fmi3FunctionTypes.h"

#define MAX_VARS 64

typedef struct {
    void *lib;
    fmi3InstantiateCoSimulationTYPE *instantiate;
    fmi3EnterInitializationModeTYPE *enter;
    fmi3ExitInitializationModeTYPE *leave;
    fmi3SetFloat64TYPE *set;
    fmi3GetFloat64TYPE *get;
    fmi3DoStepTYPE *step;
    fmi3FreeInstanceTYPE *release;
} fmu_api;

static void *need(void *lib, const char *name) {
    void *f = dlsym(lib, name);
    if (!f) {
        fprintf(stderr, "loop_floor: %s is missing\n", name);
        exit(3);
    }
    return f;
}

static void load(fmu_api *a, const char *path) {
    a->lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!a->lib) {
        fprintf(stderr, "loop_floor: cannot load %s\n", path);
        exit(3);
    }
    a->instantiate = (fmi3InstantiateCoSimulationTYPE *)need(a->lib, "fmi3InstantiateCoSimulation");
    a->enter = (fmi3EnterInitializationModeTYPE *)need(a->lib, "fmi3EnterInitializationMode");
    a->leave = (fmi3ExitInitializationModeTYPE *)need(a->lib, "fmi3ExitInitializationMode");
    a->set = (fmi3SetFloat64TYPE *)need(a->lib, "fmi3SetFloat64");
    a->get = (fmi3GetFloat64TYPE *)need(a->lib, "fmi3GetFloat64");
    a->step = (fmi3DoStepTYPE *)need(a->lib, "fmi3DoStep");
    a->release = (fmi3FreeInstanceTYPE *)need(a->lib, "fmi3FreeInstance");
}

static void read_vrs(int *n, unsigned *vr, double *val) {
    if (scanf("%d", n) != 1 || *n > MAX_VARS) exit(2);
    for (int i = 0; i < *n; i++)
        if (val ? scanf("%u %lf", &vr[i], &val[i]) != 2 : scanf("%u", &vr[i]) != 1) exit(2);
}

static double now(clockid_t clock) {
    struct timespec ts;
    clock_gettime(clock, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static fmi3Instance start(fmu_api *a, const char *token, int np, const unsigned *vr,
                          const double *val) {
    fmi3Instance c = a->instantiate("floor", token, NULL, fmi3False, fmi3False, fmi3False,
                                    fmi3False, NULL, 0, NULL, NULL, NULL);
    if (!c || a->enter(c, fmi3False, 0.0, 0.0, fmi3False, 0.0) > fmi3Warning) exit(4);
    if (a->set(c, vr, (size_t)np, val, (size_t)np) > fmi3Warning) exit(4);
    if (a->leave(c) > fmi3Warning) exit(4);
    return c;
}

int main(void) {
    char robot_lib[4096], robot_token[256], ctrl_lib[4096], ctrl_token[256];
    double h, rp_val[MAX_VARS], cp_val[MAX_VARS];
    long n_max_long, n_max_short;
    int repeats, n_rp, n_cp, n_rin, n_rout, n_cin, n_cout, i_tau_r, i_tau_l, i_conv;
    unsigned rp_vr[MAX_VARS], cp_vr[MAX_VARS], rin[MAX_VARS], rout[MAX_VARS], cin[MAX_VARS],
        cout[MAX_VARS];
    if (scanf("%4095s %255s %4095s %255s", robot_lib, robot_token, ctrl_lib, ctrl_token) != 4)
        return 2;
    if (scanf("%lf %ld %ld %d", &h, &n_max_long, &n_max_short, &repeats) != 4) return 2;
    read_vrs(&n_rp, rp_vr, rp_val);
    read_vrs(&n_cp, cp_vr, cp_val);
    n_rin = 2;
    if (scanf("%u %u", &rin[0], &rin[1]) != 2) return 2;
    read_vrs(&n_rout, rout, NULL);
    read_vrs(&n_cin, cin, NULL);
    read_vrs(&n_cout, cout, NULL);
    if (scanf("%d %d %d", &i_tau_r, &i_tau_l, &i_conv) != 3) return 2;
    fmu_api robot, ctrl;
    load(&robot, robot_lib);
    load(&ctrl, ctrl_lib);
    for (int rep = 0; rep < repeats; rep++) {
        for (int which = 0; which < 2; which++) {
            long n_max = which ? n_max_short : n_max_long, n = 0;
            fmi3Instance r = start(&robot, robot_token, n_rp, rp_vr, rp_val);
            fmi3Instance c = start(&ctrl, ctrl_token, n_cp, cp_vr, cp_val);
            double y[MAX_VARS], u[2] = {0.0, 0.0}, cu[MAX_VARS] = {0}, cy[MAX_VARS], last;
            fmi3Boolean event, terminate, early;
            if (robot.set(r, rin, 2, u, 2) > fmi3Warning) return 5;
            if (robot.get(r, rout, (size_t)n_rout, y, (size_t)n_rout) > fmi3Warning) return 5;
            double t0 = now(CLOCK_MONOTONIC), c0 = now(CLOCK_PROCESS_CPUTIME_ID);
            for (;; n++) {
                for (int i = 0; i < 5; i++) cu[i] = y[i]; /* x y theta v omega */
                if (ctrl.set(c, cin, (size_t)n_cin, cu, (size_t)n_cin) > fmi3Warning) return 6;
                if (ctrl.get(c, cout, (size_t)n_cout, cy, (size_t)n_cout) > fmi3Warning) return 6;
                int converged = cy[i_conv] != 0.0;
                cu[5] = y[5];
                cu[6] = y[6];
                if (ctrl.set(c, cin, (size_t)n_cin, cu, (size_t)n_cin) > fmi3Warning) return 6;
                if (ctrl.get(c, cout, (size_t)n_cout, cy, (size_t)n_cout) > fmi3Warning) return 6;
                if (ctrl.step(c, (double)n * h, h, fmi3True, &event, &terminate, &early, &last) >
                    fmi3Warning)
                    return 6;
                if (converged || n >= n_max) break;
                u[0] = cy[i_tau_r];
                u[1] = cy[i_tau_l];
                if (robot.set(r, rin, 2, u, 2) > fmi3Warning) return 7;
                if (robot.step(r, (double)n * h, h, fmi3True, &event, &terminate, &early, &last) >
                    fmi3Warning)
                    return 7;
                if (robot.get(r, rout, (size_t)n_rout, y, (size_t)n_rout) > fmi3Warning) return 7;
            }
            double seconds = now(CLOCK_MONOTONIC) - t0;
            double cpu = now(CLOCK_PROCESS_CPUTIME_ID) - c0;
            printf("%ld %.9f %.9f%c", n + 1, seconds, cpu, which ? '\n' : ' ');
            robot.release(r);
            ctrl.release(c);
        }
    }
    (void)n_rin;
    return 0;
}
