/* The FMU calls, the wheel servos, the rows and the block loop of two FMUs (a part of
 * wmr_stepper.c, compiled with it). */

static int fmu_set(const wmr_fmu *f) {
    if (f->fmi_version == 2)
        return ((fmi2SetRealTYPE *)f->set)(f->instance, f->in_vr, (size_t)f->n_in, f->in_val);
    return ((fmi3SetFloat64TYPE *)f->set)(f->instance, f->in_vr, (size_t)f->n_in, f->in_val,
                                          (size_t)f->n_in);
}

static int fmu_get(const wmr_fmu *f) {
    if (f->fmi_version == 2)
        return ((fmi2GetRealTYPE *)f->get)(f->instance, f->out_vr, (size_t)f->n_out, f->out_val);
    return ((fmi3GetFloat64TYPE *)f->get)(f->instance, f->out_vr, (size_t)f->n_out, f->out_val,
                                          (size_t)f->n_out);
}

static int fmu_do_step(const wmr_fmu *f, double t, double h) {
    if (f->fmi_version == 2)
        return ((fmi2DoStepTYPE *)f->do_step)(f->instance, t, h, fmi2True);
    fmi3Boolean event, terminate, early;
    fmi3Float64 last;
    return ((fmi3DoStepTYPE *)f->do_step)(f->instance, t, h, fmi3True, &event, &terminate,
                                          &early, &last);
}

/* FmuPlant.step's three calls; a status above Warning stops at the failing call. */
static int exchange(const wmr_fmu *f, double tau_r, double tau_l, double t, double h) {
    int s;
    f->in_val[0] = tau_r * f->in_gain[0] + f->in_bias[0];
    f->in_val[1] = tau_l * f->in_gain[1] + f->in_bias[1];
    if ((s = fmu_set(f)) > 1) return 16 + s;
    if ((s = fmu_do_step(f, t, h)) > 1) return 32 + s;
    if ((s = fmu_get(f)) > 1) return 48 + s;
    return 0;
}

WMR_API int wmr_exchange(const wmr_fmu *f, double tau_r, double tau_l, double t, double h) {
    return exchange(f, tau_r, tau_l, t, h);
}

/* WheelServo.update */
static double wheel_servo(const wmr_loop *s, double *integral, double omega_ref, double omega) {
    double e = omega_ref - omega;
    double ff = s->b_ff * omega_ref;
    double v, tau;
    if (s->tau_c_ff != 0.0) ff += s->tau_c_ff * tanh(omega_ref / s->w_c);
    v = s->k_p * e + *integral + ff;
    tau = v > s->torque_max ? s->torque_max : (v < -s->torque_max ? -s->torque_max : v);
    *integral += s->k_i * s->h_servo * e + s->k_t * (tau - v);
    return tau;
}

/* max(a, 0.0) as Python computes it (a NaN or a -0.0 comes back unchanged) */
static double pos_part(double a) { return 0.0 > a ? 0.0 : a; }

/* The torques held over the step just taken, then the step: peak, integral of tau^2, the
 * plant exchange at t = n h, and the work of the step (energy.step_work). */
static int plant_step(const wmr_fmu *f, wmr_loop *s, double tau_r, double tau_l) {
    const double *o = f->out_val;
    double w_r0 = o[5], w_l0 = o[6], a_r = fabs(tau_r), a_l = fabs(tau_l);
    double a, b, c, d, half;
    int code;
    if (a_r > s->peak) s->peak = a_r;
    if (a_l > s->peak) s->peak = a_l;
    s->tau_sq += (tau_r * tau_r + tau_l * tau_l) * s->h;
    code = exchange(f, tau_r, tau_l, 0.0 + (double)s->n * s->h, s->h);
    if (code) return code;
    s->n += 1;
    s->path += py_hypot(o[0] - s->x_prev, o[1] - s->y_prev);
    s->x_prev = o[0];
    s->y_prev = o[1];
    a = tau_r * w_r0;
    b = tau_r * o[5];
    c = tau_l * w_l0;
    d = tau_l * o[6];
    half = 0.5 * s->h;
    s->energy_net += half * (a + b + c + d);
    s->energy_pos += half * (pos_part(a) + pos_part(b) + pos_part(c) + pos_part(d));
    return 0;
}

/* One step of the master loop with a Python law (ServoedController): its wheel speed
 * references in, the two servos on the measured wheel speeds, the plant outputs and the
 * torques into the current row (the law's other columns the caller fills), and unless the
 * run ends here (mode 1 converged: torques logged as zero; mode 2 timeout) the plant step. */
WMR_API int wmr_servo_step(const wmr_fmu *f, wmr_loop *s, double w_r_ref, double w_l_ref,
                           int mode) {
    const double *o = f->out_val;
    double tau_r = wheel_servo(s, &s->integral_r, w_r_ref, o[5]);
    double tau_l = wheel_servo(s, &s->integral_l, w_l_ref, o[6]);
    double *row = s->block + (size_t)s->row * (size_t)s->n_cols;
    memcpy(row, o, (size_t)s->n_plant * sizeof(double));
    row[s->col_tau_r] = mode == 1 ? 0.0 : tau_r;
    row[s->col_tau_l] = mode == 1 ? 0.0 : tau_l;
    s->row += 1;
    if (mode) return 0;
    return plant_step(f, s, tau_r, tau_l);
}

/* The end of a step of a block loop: its row (the plant outputs, then the n_sig signals of
 * sig), then the run's end or the plant step with the row's torques.  Returns WMR_DONE | 1
 * (converged: the row's torques logged as zero), WMR_DONE | 2 (the last step), a failed
 * exchange's code, WMR_FULL (the block is full), or 0 to go on. */
static int block_row(const wmr_fmu *f, wmr_loop *s, const double *sig, int converged) {
    double *row = s->block + (size_t)s->row * (size_t)s->n_cols;
    int full, code;
    memcpy(row, f->out_val, (size_t)s->n_plant * sizeof(double));
    memcpy(row + s->n_plant, sig, (size_t)s->n_sig * sizeof(double));
    s->row += 1;
    if (converged) {
        row[s->col_tau_r] = 0.0;
        row[s->col_tau_l] = 0.0;
        return WMR_DONE | 1;
    }
    if (s->n >= s->n_max) return WMR_DONE | 2;
    full = s->row == s->rows_max;
    if ((code = plant_step(f, s, row[s->col_tau_r], row[s->col_tau_l]))) return code;
    return full ? WMR_FULL : 0;
}

/* The closed loop of two FMUs, rows until the block is full or the run ends: per step
 * exactly FmuController's calls (converged: set, get; step: set, get, doStep at its own
 * clock t = n h) and the robot's exchange.  Returns WMR_DONE | 1 (converged) or | 2
 * (timeout), WMR_FULL, WMR_NONFINITE or a failed call's code. */
WMR_API int wmr_fmu_loop(const wmr_fmu *f, const wmr_fmu *c, wmr_loop *s) {
    const double *o = f->out_val;
    double *ci = c->in_val;
    const double *co = c->out_val;
    int code;
    for (;;) {
        int converged;
        if (!(isfinite(o[0]) && isfinite(o[1]) && isfinite(o[2]))) return WMR_NONFINITE;
        ci[0] = o[0];
        ci[1] = o[1];
        ci[2] = o[2];
        ci[3] = o[3];
        ci[4] = o[4];
        if ((code = fmu_set(c)) > 1) return WMR_CTRL + 16 + code;
        if ((code = fmu_get(c)) > 1) return WMR_CTRL + 48 + code;
        converged = co[s->i_converged] != 0.0;
        ci[5] = o[5];
        ci[6] = o[6];
        if ((code = fmu_set(c)) > 1) return WMR_CTRL + 16 + code;
        if ((code = fmu_get(c)) > 1) return WMR_CTRL + 48 + code;
        /* a failed sample is not logged: FmuController.step raises before the row (doStep
         * leaves the outputs read by the get above as they are) */
        if ((code = fmu_do_step(c, (double)s->n * s->h, s->h)) > 1) return WMR_CTRL + 32 + code;
        if ((code = block_row(f, s, co, converged))) return code;
    }
}
