/*
 * wmr_stepper.c: the master loop's per-step work in one C call (host only).
 *
 * Not part of any FMU.  `wmr.build.fmus.build_stepper` compiles it with the host's C
 * compiler beside the FMUs; `wmr.adapters.fmi.robot` loads it with ctypes and hands it the
 * FMU's own FMI entry points (the addresses fmpy resolved), so that a control step costs one
 * call from Python instead of three (set inputs, doStep, get outputs) plus the servo and
 * bookkeeping arithmetic.  Without it the same work runs in Python: both give the same bits.
 *
 * Bit-identity with the Python code is the contract: every expression below is the Python
 * expression it replaces, in the same order, each operation rounded on its own (no fused
 * multiply-add: built with -ffp-contract=off, and the pragma for clang).
 *
 * The library also holds the paper's law itself (with the controller FMU's generated
 * model_sizes.h and model_indices.h on the include path), the
 * controller FMU's own core (fmu/src/controller/controller.c), so that a run of the Python
 * stabiliser on the robot FMU runs whole blocks of the closed loop in C (wmr_law_loop) with
 * the bits of the Python law: the same operations in the same order, math.hypot's algorithm,
 * and the run's goal heading and tolerance in the Python run's own radians.
 *
 * Status codes: 0 OK; 16 * (call + 1) + FMI status for a call that returned above Warning
 * (call 0 set, 1 doStep, 2 get) of the robot FMU, 64 + the same for the controller FMU;
 * WMR_NONFINITE for a non-finite pose; WMR_DONE and WMR_FULL from wmr_fmu_loop.
 */
#include <math.h>
#include <stddef.h>
#include <string.h>

#include "fmi2FunctionTypes.h"
#include "fmi3FunctionTypes.h"

#if defined(__clang__)
#pragma STDC FP_CONTRACT OFF
#endif

#if defined(_WIN32)
#define WMR_API __declspec(dllexport)
#else
#define WMR_API __attribute__((visibility("default")))
#endif

#define WMR_CTRL 64
#define WMR_MAX_TOPICS 32 /* per-step topics a chunk encoder takes */
#define WMR_NONFINITE 256
#define WMR_DONE 512
#define WMR_FULL 1024

/* the paper's law: the controller FMU's core (its index headers come from the build) */
#define WMR_UNITY /* the law's functions get internal linkage, as in the FMU */
#include "controller.c"

/* One FMU instance and its prebuilt exchange arrays (mirrored by ctypes in robot.py). */
typedef struct {
    int fmi_version;
    int n_in;
    int n_out;
    int pad;
    void *instance;
    void *set;
    void *do_step;
    void *get;
    const unsigned int *in_vr;
    const unsigned int *out_vr;
    double *in_val;
    double *out_val;
    double in_gain[2]; /* theirs = ours * gain + bias, the two torques of the robot */
    double in_bias[2];
} wmr_fmu;

/* The wheel servos, the run's accumulators and the row being written. */
typedef struct {
    /* WheelServo (actuator.py), both wheels alike */
    double k_p, k_i, torque_max, h_servo, b_ff, tau_c_ff, w_c, k_t;
    double integral_r, integral_l;
    /* run_closed_loop's accumulators */
    double energy_net, energy_pos, tau_sq, peak;
    double h;          /* control period, s */
    double path;       /* path length, m: the sum of math.hypot of the steps, in their order */
    double x_prev, y_prev; /* the position before the last step */
    long long n;       /* control step: the FMUs are at t = n h */
    long long n_max;   /* last step of a run that does not converge */
    double *block;     /* (rows, n_cols) float64, C order */
    int n_cols, row, rows_max, n_plant, n_sig, col_tau_r, col_tau_l, i_converged;
} wmr_loop;

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



/* One run of the compiled law: its parameters (the controller FMU's, in its order), its
 * discrete state and the goal heading and tolerance in rad (mirrored by ctypes). */
typedef struct {
    const double *p;
    double *z;
    double theta_d;
    double tol;
} wmr_law;

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

/* ---------------------------------------------------------------------------------------------
 * The MCAP Message records of a block of rows, all per-step topics: the bytes of
 * wmr.adapters.mcap.schemas.RowEncoder.encode (one record per row and topic, row after row,
 * topic after topic: opcode, length, channel id, sequence 0, log time = publish time = t_ns,
 * then the protobuf message: field 1 the Timestamp, then the topic's fixed body with the
 * row's doubles in its slots).  src is (n, n_src) float64: the signals and the derived
 * columns (the heading quaternion, computed by numpy as RowEncoder does).  Returns the bytes
 * written to out (room for n rows of the longest records) and the offset of each record.
 */
static void put_u64(unsigned char *p, unsigned long long v) {
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
    memcpy(p, &v, 8); /* one store, where the byte loop below was eight */
#else
    for (int j = 0; j < 8; j++) p[j] = (unsigned char)(v >> (8 * j));
#endif
}

/* a protobuf varint field (tag, then 7 bits a byte), omitted when the value is 0 */
static int put_varint_field(unsigned char *p, unsigned char tag, unsigned long long v) {
    int len = 0;
    if (v == 0) return 0;
    p[len++] = tag;
    while (v >= 0x80) {
        p[len++] = (unsigned char)(v & 0x7F) | 0x80;
        v >>= 7;
    }
    p[len++] = (unsigned char)v;
    return len;
}

/* A Message record's head: opcode, record length, channel id, sequence, log and publish time */
static void put_message_head(unsigned char *r, int channel, unsigned int sequence,
                             unsigned long long t, size_t data_len) {
    r[0] = 0x05; /* Message */
    put_u64(r + 1, 2 + 4 + 8 + 8 + data_len);
    r[9] = (unsigned char)(channel & 0xFF);
    r[10] = (unsigned char)(channel >> 8);
    r[11] = (unsigned char)sequence;
    r[12] = (unsigned char)(sequence >> 8);
    r[13] = (unsigned char)(sequence >> 16);
    r[14] = (unsigned char)(sequence >> 24);
    put_u64(r + 15, t);
    put_u64(r + 23, t);
}

/* The per-step topics' layout (wmr.adapters.mcap.schemas.TopicLayout), set once per
 * encoder: each topic's channel id and fixed body, and its slots (offset in the body, source
 * column).  Source columns below n_sig are the row's signals; the others its extra columns
 * (the heading quaternion). */
typedef struct {
    int n_sig, n_extra, n_topics;
    const int *channel, *body_len;
    const unsigned char *bodies;
    const int *n_slots, *slot_off, *slot_src;
} wmr_layout;

/* Row i's records, at out; each record's offset (from base) in offsets[k] */
static size_t encode_row(const wmr_layout *L, unsigned long long t, const double *row,
                         const double *extra, unsigned char *out, size_t base,
                         long long *offsets) {
    unsigned char ts[12];
    int ts_len = put_varint_field(ts, 0x08, t / 1000000000ULL);
    ts_len += put_varint_field(ts + ts_len, 0x10, t % 1000000000ULL);
    const unsigned char *body = L->bodies;
    const int *off = L->slot_off, *from = L->slot_src;
    size_t pos = 0;
    for (int k = 0; k < L->n_topics; k++) {
        unsigned char *r = out + pos;
        size_t data_len = 2 + (size_t)ts_len + (size_t)L->body_len[k];
        offsets[k] = (long long)(base + pos);
        put_message_head(r, L->channel[k], 0, t, data_len);
        r[31] = 0x0A; /* Timestamp, length-delimited */
        r[32] = (unsigned char)ts_len;
        memcpy(r + 33, ts, (size_t)ts_len);
        unsigned char *b = r + 33 + ts_len;
        memcpy(b, body, (size_t)L->body_len[k]);
        for (int s = 0; s < L->n_slots[k]; s++) {
            const double *v = from[s] < L->n_sig ? row + from[s] : extra + (from[s] - L->n_sig);
            memcpy(b + off[s], v, 8);
        }
        pos += 31 + data_len;
        body += L->body_len[k];
        off += L->n_slots[k];
        from += L->n_slots[k];
    }
    return pos;
}

WMR_API long long wmr_encode_rows(int n, const long long *t_ns, const double *src, int n_src,
                                  int n_topics, const int *channel, const int *body_len,
                                  const unsigned char *bodies, const int *n_slots,
                                  const int *slot_off, const int *slot_src, unsigned char *out,
                                  long long *offsets) {
    wmr_layout L = {n_src, 0, n_topics, channel, body_len, bodies, n_slots, slot_off, slot_src};
    size_t pos = 0;
    for (int i = 0; i < n; i++)
        pos += encode_row(&L, (unsigned long long)t_ns[i], src + (size_t)i * (size_t)n_src,
                          NULL, out + pos, pos, offsets + (size_t)i * (size_t)n_topics);
    return (long long)pos;
}

/* A chunk's rows: the records of wmr_encode_rows (the signals in block, n x n_sig, the extra
 * columns in extra, n x n_extra), and the chunk's Message Index records at index, one per
 * topic in topic order, as mcap packs them: opcode 0x07, record length, channel id, length of
 * the entries, then (log time, record offset) per row.  Returns the records' bytes. */
WMR_API long long wmr_encode_chunk(const wmr_layout *L, int n, const long long *t_ns,
                                   const double *block, const double *extra,
                                   unsigned char *out, unsigned char *index) {
    size_t pos = 0, entries = 16 * (size_t)n, rec = 15 + entries;
    long long offsets[WMR_MAX_TOPICS];
    if (L->n_topics > WMR_MAX_TOPICS) return -1;
    for (int k = 0; k < L->n_topics; k++) {
        unsigned char *m = index + (size_t)k * rec;
        m[0] = 0x07; /* Message Index */
        put_u64(m + 1, 6 + entries);
        m[9] = (unsigned char)(L->channel[k] & 0xFF);
        m[10] = (unsigned char)(L->channel[k] >> 8);
        m[11] = (unsigned char)entries;
        m[12] = (unsigned char)(entries >> 8);
        m[13] = (unsigned char)(entries >> 16);
        m[14] = (unsigned char)(entries >> 24);
    }
    for (int i = 0; i < n; i++) {
        unsigned long long t = (unsigned long long)t_ns[i];
        pos += encode_row(L, t, block + (size_t)i * (size_t)L->n_sig,
                          extra + (size_t)i * (size_t)L->n_extra, out + pos, pos, offsets);
        for (int k = 0; k < L->n_topics; k++) {
            unsigned char *e = index + (size_t)k * rec + 15 + 16 * (size_t)i;
            put_u64(e, t);
            put_u64(e + 8, (unsigned long long)offsets[k]);
        }
    }
    return (long long)pos;
}
