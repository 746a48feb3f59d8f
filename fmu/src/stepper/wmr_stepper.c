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
 * One library, one compile: this file includes its parts, each a job of its own (unity build:
 * their helpers stay internal, as in one file), and wmr_stepper.h holds what Python sees:
 *   exchange.c  the FMU calls, the wheel servos, the rows and the block loop of two FMUs;
 *   law.c       the paper's law compiled in, and its block loop;
 *   encode.c    the MCAP Message records of the per-step topics and their indexes.
 */
#include <math.h>
#include <stddef.h>
#include <string.h>

#include "fmi2FunctionTypes.h"
#include "fmi3FunctionTypes.h"

#if defined(__clang__)
#pragma STDC FP_CONTRACT OFF
#endif

#include "wmr_stepper.h"

/* the paper's law: the controller FMU's core (its index headers come from the build) */
#define WMR_UNITY /* the law's functions get internal linkage, as in the FMU */
#include "controller.c"

#include "exchange.c"
#include "law.c"
#include "encode.c"
