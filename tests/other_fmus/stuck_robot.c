/* fatal_robot.c whose fmi2DoStep misbehaves from t = MISBEHAVE_AT_S on, as a foreign FMU may
 * (tests/test_stopping.py): compiled with -DLOOPS it spins for ever in C (a solver that never
 * converges), with -DCRASHES it writes through NULL (SIGSEGV). */
#define fmi2DoStep fatal_robot_do_step
#include "fatal_robot.c"
#undef fmi2DoStep

#ifndef MISBEHAVE_AT_S
#define MISBEHAVE_AT_S 2.0
#endif

static volatile int spinning = 1;

int fmi2DoStep(void *c, double t, double h, int no_prior) {
    if (t >= MISBEHAVE_AT_S) {
#if defined(LOOPS)
        while (spinning) {
        }
#elif defined(CRASHES)
        *(volatile int *)NULL = 1;
#endif
    }
    return fatal_robot_do_step(c, t, h, no_prior);
}
