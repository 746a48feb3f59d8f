/*
 * solver.c: Dormand-Prince 5(4) with FSAL and PI step-size control.
 *
 * Coefficients and controller constants follow Hairer, Norsett & Wanner,
 * "Solving Ordinary Differential Equations I", 2nd ed., Sec. II.4/II.5 and
 * the DOPRI5 code (safety 0.9, step ratio within [0.2, 10], PI beta 0.04).
 */
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "solver.h"

#define NX MODEL_NX

/* Butcher tableau */
static const double C2 = 1.0 / 5.0, C3 = 3.0 / 10.0, C4 = 4.0 / 5.0, C5 = 8.0 / 9.0;
static const double A21 = 1.0 / 5.0;
static const double A31 = 3.0 / 40.0, A32 = 9.0 / 40.0;
static const double A41 = 44.0 / 45.0, A42 = -56.0 / 15.0, A43 = 32.0 / 9.0;
static const double A51 = 19372.0 / 6561.0, A52 = -25360.0 / 2187.0,
                    A53 = 64448.0 / 6561.0, A54 = -212.0 / 729.0;
static const double A61 = 9017.0 / 3168.0, A62 = -355.0 / 33.0, A63 = 46732.0 / 5247.0,
                    A64 = 49.0 / 176.0, A65 = -5103.0 / 18656.0;
static const double A71 = 35.0 / 384.0, A73 = 500.0 / 1113.0, A74 = 125.0 / 192.0,
                    A75 = -2187.0 / 6784.0, A76 = 11.0 / 84.0;
/* error coefficients: 5th-order minus embedded 4th-order weights */
static const double E1 = 71.0 / 57600.0, E3 = -71.0 / 16695.0, E4 = 71.0 / 1920.0,
                    E5 = -17253.0 / 339200.0, E6 = 22.0 / 525.0, E7 = -1.0 / 40.0;

/* controller */
static const double SAFETY = 0.9;
static const double FAC_MIN = 0.2;   /* h_new >= 0.2 h */
static const double FAC_MAX = 10.0;  /* h_new <= 10 h */
static const double BETA = 0.04;     /* PI stabilisation */
static const double EXPO1 = 0.2 - 0.04 * 0.75;
static const double ERR_OLD_INIT = 1e-4;

static void set_msg(char *msg, size_t size, const char *fmt, ...) {
    va_list ap;
    if (!msg || size == 0) return;
    va_start(ap, fmt);
    vsnprintf(msg, size, fmt, ap);
    va_end(ap);
}

WMR_INTERNAL
const char *solver_status_name(SolverStatus status) {
    switch (status) {
    case SOLVER_OK: return "ok";
    case SOLVER_BAD_ARGUMENT: return "bad argument";
    case SOLVER_MODEL_ERROR: return "model error";
    case SOLVER_NONFINITE: return "non-finite value";
    case SOLVER_MAX_STEPS: return "too many steps";
    case SOLVER_STEP_TOO_SMALL: return "step size too small";
    }
    return "unknown";
}

WMR_INTERNAL
void solver_init(SolverState *s) {
    memset(s, 0, sizeof(*s));
    s->rtol = SOLVER_DEFAULT_RTOL;
    s->atol = SOLVER_DEFAULT_ATOL;
    s->max_steps = SOLVER_DEFAULT_MAX_STEPS;
    s->h_hint = 0.0;
    s->err_old = ERR_OLD_INIT;
}

WMR_INTERNAL
void solver_reset_hint(SolverState *s) {
    s->h_hint = 0.0;
    s->err_old = ERR_OLD_INIT;
}

/* One evaluation of the right-hand side with checks. */
static SolverStatus rhs(SolverState *s, double t, const double x[NX], const double u[],
                        const double p[], double dx[NX], char *msg, size_t msg_size) {
    int i;
    s->n_rhs++;
    if (model_derivatives(x, u, p, dx) != 0) {
        set_msg(msg, msg_size, "model_derivatives failed at t = %.17g", t);
        return SOLVER_MODEL_ERROR;
    }
    for (i = 0; i < NX; i++) {
        if (!isfinite(dx[i])) {
            set_msg(msg, msg_size,
                    "derivative of state %d is %g at t = %.17g (state %d = %.17g)",
                    i, dx[i], t, i, x[i]);
            return SOLVER_NONFINITE;
        }
    }
    return SOLVER_OK;
}

/* Initial step size guess (Hairer's HINIT), order 5. */
static SolverStatus initial_step(SolverState *s, double t, const double x[NX],
                                 const double f0[NX], const double u[], const double p[],
                                 double hmax, double *h_out, char *msg, size_t msg_size) {
    double dnf = 0.0, dny = 0.0, der2 = 0.0, der12, h, h1, sk;
    double x1[NX], f1[NX];
    SolverStatus st;
    int i;

    for (i = 0; i < NX; i++) {
        sk = s->atol + s->rtol * fabs(x[i]);
        dnf += (f0[i] / sk) * (f0[i] / sk);
        dny += (x[i] / sk) * (x[i] / sk);
    }
    if (dnf <= 1e-10 || dny <= 1e-10)
        h = 1e-6;
    else
        h = 0.01 * sqrt(dny / dnf);
    if (h > hmax) h = hmax;

    for (i = 0; i < NX; i++) x1[i] = x[i] + h * f0[i];
    st = rhs(s, t + h, x1, u, p, f1, msg, msg_size);
    if (st != SOLVER_OK) return st;

    for (i = 0; i < NX; i++) {
        sk = s->atol + s->rtol * fabs(x[i]);
        der2 += ((f1[i] - f0[i]) / sk) * ((f1[i] - f0[i]) / sk);
    }
    der2 = sqrt(der2) / h;
    der12 = der2 > sqrt(dnf) ? der2 : sqrt(dnf);
    if (der12 <= 1e-15)
        h1 = (1e-6 > h * 1e-3) ? 1e-6 : h * 1e-3;
    else
        h1 = pow(0.01 / der12, 1.0 / 5.0);

    h = 100.0 * h;
    if (h1 < h) h = h1;
    if (hmax < h) h = hmax;
    *h_out = h;
    return SOLVER_OK;
}

WMR_INTERNAL
SolverStatus solver_integrate(SolverState *s, double t0, double t1,
                              double x_io[MODEL_NX], const double u[MODEL_NU],
                              const double p[MODEL_NP],
                              char *msg, size_t msg_size) {
    double x[NX], xs[NX], xn[NX];
    double k1[NX], k2[NX], k3[NX], k4[NX], k5[NX], k6[NX], k7[NX];
    double t, h, h_new, err, fac, fac11, sk, e, hmax, h_min;
    int i, last, rejected = 0, truncated;
    long n_steps = 0;
    double h_untruncated;
    SolverStatus st;

    if (msg && msg_size) msg[0] = '\0';

    if (!isfinite(t0) || !isfinite(t1) || !(t1 > t0)) {
        set_msg(msg, msg_size, "invalid integration interval [%.17g, %.17g]", t0, t1);
        return SOLVER_BAD_ARGUMENT;
    }
    if (!(s->rtol > 0.0) || !(s->atol > 0.0) || !isfinite(s->rtol) || !isfinite(s->atol) ||
        s->max_steps <= 0) {
        set_msg(msg, msg_size, "invalid solver settings rtol = %g, atol = %g, max_steps = %ld",
                s->rtol, s->atol, s->max_steps);
        return SOLVER_BAD_ARGUMENT;
    }
    for (i = 0; i < NX; i++) {
        if (!isfinite(x_io[i])) {
            set_msg(msg, msg_size, "state %d is %g at t = %.17g", i, x_io[i], t0);
            return SOLVER_NONFINITE;
        }
        x[i] = x_io[i];
    }

    hmax = t1 - t0;
    t = t0;

    /* k1 = f(t0, x0); u or p may have changed since the last call, so the
     * FSAL derivative of the previous call cannot be reused. */
    st = rhs(s, t, x, u, p, k1, msg, msg_size);
    if (st != SOLVER_OK) return st;

    if (s->h_hint > 0.0 && isfinite(s->h_hint)) {
        h = s->h_hint;
    } else {
        st = initial_step(s, t, x, k1, u, p, hmax, &h, msg, msg_size);
        if (st != SOLVER_OK) return st;
    }

    for (;;) {
        /* land exactly on t1; stretch by up to 10 % to avoid a sliver step */
        h_untruncated = h;
        truncated = 0;
        last = 0;
        if (t + 1.1 * h >= t1) {
            h = t1 - t;
            truncated = 1;
            last = 1;
        }
        h_min = 16.0 * DBL_EPSILON * (fabs(t) > fabs(t1) ? fabs(t) : fabs(t1));
        if (!(h > h_min)) {
            set_msg(msg, msg_size,
                    "step size %g too small at t = %.17g (stiff or singular dynamics)", h, t);
            return SOLVER_STEP_TOO_SMALL;
        }
        if (++n_steps > s->max_steps) {
            set_msg(msg, msg_size,
                    "more than %ld internal steps between t = %.17g and %.17g (reached t = %.17g, h = %g)",
                    s->max_steps, t0, t1, t, h);
            return SOLVER_MAX_STEPS;
        }

        for (i = 0; i < NX; i++) xs[i] = x[i] + h * A21 * k1[i];
        if ((st = rhs(s, t + C2 * h, xs, u, p, k2, msg, msg_size)) != SOLVER_OK) return st;
        for (i = 0; i < NX; i++) xs[i] = x[i] + h * (A31 * k1[i] + A32 * k2[i]);
        if ((st = rhs(s, t + C3 * h, xs, u, p, k3, msg, msg_size)) != SOLVER_OK) return st;
        for (i = 0; i < NX; i++) xs[i] = x[i] + h * (A41 * k1[i] + A42 * k2[i] + A43 * k3[i]);
        if ((st = rhs(s, t + C4 * h, xs, u, p, k4, msg, msg_size)) != SOLVER_OK) return st;
        for (i = 0; i < NX; i++)
            xs[i] = x[i] + h * (A51 * k1[i] + A52 * k2[i] + A53 * k3[i] + A54 * k4[i]);
        if ((st = rhs(s, t + C5 * h, xs, u, p, k5, msg, msg_size)) != SOLVER_OK) return st;
        for (i = 0; i < NX; i++)
            xs[i] = x[i] + h * (A61 * k1[i] + A62 * k2[i] + A63 * k3[i] + A64 * k4[i] +
                                A65 * k5[i]);
        if ((st = rhs(s, last ? t1 : t + h, xs, u, p, k6, msg, msg_size)) != SOLVER_OK) return st;
        for (i = 0; i < NX; i++)
            xn[i] = x[i] + h * (A71 * k1[i] + A73 * k3[i] + A74 * k4[i] + A75 * k5[i] +
                                A76 * k6[i]);
        if ((st = rhs(s, last ? t1 : t + h, xn, u, p, k7, msg, msg_size)) != SOLVER_OK) return st;

        /* RMS error norm */
        err = 0.0;
        for (i = 0; i < NX; i++) {
            sk = s->atol + s->rtol * (fabs(x[i]) > fabs(xn[i]) ? fabs(x[i]) : fabs(xn[i]));
            e = h * (E1 * k1[i] + E3 * k3[i] + E4 * k4[i] + E5 * k5[i] + E6 * k6[i] +
                     E7 * k7[i]) / sk;
            err += e * e;
        }
        err = sqrt(err / NX);
        if (!isfinite(err)) {
            set_msg(msg, msg_size, "non-finite error estimate at t = %.17g, h = %g", t, h);
            return SOLVER_NONFINITE;
        }

        fac11 = pow(err, EXPO1);
        if (err <= 1.0) {
            /* accept */
            fac = fac11 / pow(s->err_old, BETA) / SAFETY;
            if (fac < 1.0 / FAC_MAX) fac = 1.0 / FAC_MAX;
            if (fac > 1.0 / FAC_MIN) fac = 1.0 / FAC_MIN;
            h_new = h / fac;
            if (rejected && h_new > h) h_new = h;
            s->err_old = err > ERR_OLD_INIT ? err : ERR_OLD_INIT;
            s->n_accepted++;
            for (i = 0; i < NX; i++) {
                x[i] = xn[i];
                k1[i] = k7[i]; /* FSAL */
            }
            if (last) {
                /* keep the natural step size as the hint for the next call */
                if (truncated && !rejected && h_untruncated > h_new) h_new = h_untruncated;
                s->h_hint = h_new;
                for (i = 0; i < NX; i++) x_io[i] = x[i];
                return SOLVER_OK;
            }
            t = t + h;
            h = h_new;
            rejected = 0;
        } else {
            /* reject */
            fac = fac11 / SAFETY;
            if (fac > 1.0 / FAC_MIN) fac = 1.0 / FAC_MIN;
            h = h / fac;
            rejected = 1;
            s->n_rejected++;
        }
    }
}
