/*
 * solver.h: adaptive Dormand-Prince 5(4) integrator for the model core.
 *
 * Integrates dx/dt = model_derivatives(x, u, p) from t0 to t1 with u and p
 * held constant (a co-simulation communication step), landing exactly on t1.
 * Error control: mixed absolute/relative error per state, RMS norm, the
 * 5th-order solution is propagated (local extrapolation), FSAL, and the PI
 * step-size controller of Hairer & Wanner's DOPRI5.
 *
 * All state lives in a SolverState, a plain struct without pointers that may
 * be copied with memcpy (FMU state get/set/serialize).  There is no static
 * or global mutable state: instances may run in parallel threads.
 */
#ifndef WMR_SOLVER_H
#define WMR_SOLVER_H

#include <stddef.h>

#include "model.h"

#define SOLVER_DEFAULT_RTOL 1e-9
#define SOLVER_DEFAULT_ATOL 1e-10
#define SOLVER_DEFAULT_MAX_STEPS 100000L /* internal steps (accepted + rejected) per call */

typedef enum {
    SOLVER_OK = 0,
    SOLVER_BAD_ARGUMENT,  /* t1 <= t0, non-finite times, bad tolerances */
    SOLVER_MODEL_ERROR,   /* model_derivatives returned non-zero */
    SOLVER_NONFINITE,     /* a derivative or a state became NaN or Inf */
    SOLVER_MAX_STEPS,     /* more than max_steps internal steps in one call */
    SOLVER_STEP_TOO_SMALL /* step size underflow (stiffness or a singularity) */
} SolverStatus;

typedef struct {
    /* settings */
    double rtol;      /* relative tolerance */
    double atol;      /* absolute tolerance */
    long max_steps;   /* max internal step attempts per solver_integrate call */
    /* memory carried across calls */
    double h_hint;    /* last good internal step size, 0: none yet */
    double err_old;   /* PI controller memory (previous accepted error norm) */
    /* statistics since solver_init */
    unsigned long n_accepted;
    unsigned long n_rejected;
    unsigned long n_rhs;
} SolverState;

/* Default settings, no step size hint, statistics zeroed. */
WMR_INTERNAL
void solver_init(SolverState *s);

/* Forget the step-size memory (after a discontinuous change of x). */
WMR_INTERNAL
void solver_reset_hint(SolverState *s);

/* Integrate x from t0 to t1 (t1 > t0).  On SOLVER_OK, x holds the state at
 * exactly t1.  On failure x is left unchanged and a message (NUL-terminated,
 * at most msg_size bytes) explains the failure; msg may be NULL. */
WMR_INTERNAL
SolverStatus solver_integrate(SolverState *s, double t0, double t1,
                              double x[MODEL_NX], const double u[MODEL_NU],
                              const double p[MODEL_NP],
                              char *msg, size_t msg_size);

WMR_INTERNAL
const char *solver_status_name(SolverStatus status);

#endif
