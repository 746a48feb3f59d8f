/* The paper's law compiled in (the controller FMU's core, included by wmr_stepper.c) and its
 * block loop (a part of wmr_stepper.c, compiled with it). */

WMR_API void wmr_law_sizes(int *np, int *nu, int *ny, int *nx) {
    *np = MODEL_NP;
    *nu = MODEL_NU;
    *ny = MODEL_NY;
    *nx = MODEL_NX;
}

/* One sample of the law (for the tests and the self-check: the Python law, bit for bit). */
WMR_API void wmr_law_sample(const wmr_law *c, const double *u, double *y, double *z_next) {
    sample(c->z, u, c->p, c->theta_d, c->tol, y, z_next);
}

WMR_API double wmr_law_hypot(double a, double b) { return py_hypot(a, b); }

/* The closed loop of the compiled law and the robot FMU, rows until the block is full or the
 * run ends: per step the Python path's order (converged on the state before the sample, the
 * sample, the row, then the plant step unless the run ends).  Returns as wmr_fmu_loop. */
WMR_API int wmr_law_loop(const wmr_fmu *f, wmr_law *c, wmr_loop *s) {
    const double *o = f->out_val;
    double u[MODEL_NU], y[MODEL_NY], z_next[MODEL_NX];
    int code;
    for (;;) {
        if (!(isfinite(o[0]) && isfinite(o[1]) && isfinite(o[2]))) return WMR_NONFINITE;
        u[U_x] = o[0];
        u[U_y] = o[1];
        u[U_theta] = o[2];
        u[U_v] = o[3];
        u[U_omega] = o[4];
        u[U_omega_r] = o[5];
        u[U_omega_l] = o[6];
        sample(c->z, u, c->p, c->theta_d, c->tol, y, z_next);
        memcpy(c->z, z_next, sizeof z_next);
        if ((code = block_row(f, s, y, y[Y_converged] != 0.0))) return code;
    }
}
