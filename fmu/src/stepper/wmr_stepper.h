/*
 * wmr_stepper.h: what the C stepper shares with Python, in one place.
 *
 * The structs below are the stepper's side of the ctypes views of
 * pipelines/wmr/adapters/stepper (FmuCall, LoopState, LawCall, Layout): tests/test_stepper.py
 * reads this header and compares every struct, field by field and type by type, with the
 * view's _fields_, so that a field added here cannot be missed there.  Keep the format strict:
 * one field per line, "type name;" or "type name[N];", a comment after it if any.
 *
 * Status codes: 0 OK; 16 * (call + 1) + FMI status for a call that returned above Warning
 * (call 0 set, 1 doStep, 2 get) of the robot FMU, WMR_CTRL + the same for the controller FMU;
 * WMR_NONFINITE for a non-finite pose; WMR_DONE (| 1 converged, | 2 timeout) and WMR_FULL
 * from the block loops.
 */
#ifndef WMR_STEPPER_H
#define WMR_STEPPER_H

#if defined(_WIN32)
#define WMR_API __declspec(dllexport)
#else
#define WMR_API __attribute__((visibility("default")))
#endif

#define WMR_CTRL 64
#define WMR_NONFINITE 256
#define WMR_DONE 512
#define WMR_FULL 1024
#define WMR_MAX_TOPICS 32 /* per-step topics a chunk encoder takes */

/* One FMU instance and its prebuilt exchange arrays (FmuCall). */
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

/* The wheel servos, the run's accumulators and the row being written (LoopState). */
typedef struct {
    double k_p; /* WheelServo (actuator.py), both wheels alike */
    double k_i;
    double torque_max;
    double h_servo;
    double b_ff;
    double tau_c_ff;
    double w_c;
    double k_t;
    double integral_r;
    double integral_l;
    double energy_net; /* run_closed_loop's accumulators */
    double energy_pos;
    double tau_sq;
    double peak;
    double h; /* control period, s */
    double path; /* path length, m: the sum of math.hypot of the steps, in their order */
    double x_prev; /* the position before the last step */
    double y_prev;
    long long n; /* control step: the FMUs are at t = n h */
    long long n_max; /* last step of a run that does not converge */
    double *block; /* (rows, n_cols) float64, C order */
    int n_cols;
    int row;
    int rows_max;
    int n_plant;
    int n_sig;
    int col_tau_r;
    int col_tau_l;
    int i_converged;
} wmr_loop;

/* One run of the compiled law: its parameters (the controller FMU's, in its order), its
 * discrete state and the goal heading and tolerance in rad (LawCall). */
typedef struct {
    const double *p;
    double *z;
    double theta_d;
    double tol;
} wmr_law;

/* The per-step topics' layout (wmr.adapters.mcap.schemas.TopicLayout), set once per encoder:
 * each topic's channel id and fixed body, and its slots (offset in the body, source column).
 * Source columns below n_sig are the row's signals; the others its extra columns (the heading
 * quaternion) (Layout). */
typedef struct {
    int n_sig;
    int n_extra;
    int n_topics;
    const int *channel;
    const int *body_len;
    const unsigned char *bodies;
    const int *n_slots;
    const int *slot_off;
    const int *slot_src;
} wmr_layout;

/* exchange.c: the FMU calls, the wheel servos and the block loops of the master */
WMR_API int wmr_exchange(const wmr_fmu *f, double tau_r, double tau_l, double t, double h);
WMR_API int wmr_servo_step(const wmr_fmu *f, wmr_loop *s, double w_r_ref, double w_l_ref,
                           int mode);
WMR_API int wmr_fmu_loop(const wmr_fmu *f, const wmr_fmu *c, wmr_loop *s);

/* law.c: the paper's law compiled in */
WMR_API void wmr_law_sizes(int *np, int *nu, int *ny, int *nx);
WMR_API void wmr_law_sample(const wmr_law *c, const double *u, double *y, double *z_next);
WMR_API double wmr_law_hypot(double a, double b);
WMR_API int wmr_law_loop(const wmr_fmu *f, wmr_law *c, wmr_loop *s);

/* encode.c: the MCAP records of the per-step topics */
WMR_API long long wmr_encode_rows(int n, const long long *t_ns, const double *src, int n_src,
                                  int n_topics, const int *channel, const int *body_len,
                                  const unsigned char *bodies, const int *n_slots,
                                  const int *slot_off, const int *slot_src, unsigned char *out,
                                  long long *offsets);
WMR_API long long wmr_encode_chunk(const wmr_layout *L, int n, const long long *t_ns,
                                   const double *block, const double *extra,
                                   unsigned char *out, unsigned char *index);

#endif
