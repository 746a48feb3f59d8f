"""Symbol hygiene: the sources of our FMUs compile with FMI2_FUNCTION_PREFIX /
FMI3_FUNCTION_PREFIX into objects whose only global symbols are the prefixed fmi* functions,
and three of them (two FMI 2.0 copies, one FMI 3.0) link statically into one program that runs
each and gets the shared library's result."""

from __future__ import annotations

import shutil
import subprocess
import zipfile
from pathlib import Path

import pytest
from fmpy import read_model_description

from wmr.adapters.fmi.robot import FmuPlant
from wmr.build.codegen import internal_linkage
from wmr.build.fmus import BuildResult
from wmr.core.plant import Pose, RobotParams
from wmr.infra.errors import BuildError

N_STEPS, H, TAU = 100, 0.01, (1.0, 0.8)

MAIN = r"""
#include <stdio.h>
#include <stdarg.h>
#include "fmi2FunctionTypes.h"
#include "fmi3FunctionTypes.h"

/* the entry points of the three copies, by their prefixed names */
#define DECLARE2(P) \
    fmi2GetVersionTYPE P##fmi2GetVersion; fmi2InstantiateTYPE P##fmi2Instantiate; \
    fmi2SetupExperimentTYPE P##fmi2SetupExperiment; \
    fmi2EnterInitializationModeTYPE P##fmi2EnterInitializationMode; \
    fmi2ExitInitializationModeTYPE P##fmi2ExitInitializationMode; \
    fmi2SetRealTYPE P##fmi2SetReal; fmi2GetRealTYPE P##fmi2GetReal; \
    fmi2DoStepTYPE P##fmi2DoStep; fmi2FreeInstanceTYPE P##fmi2FreeInstance;
DECLARE2(A_)
DECLARE2(B_)
fmi3InstantiateCoSimulationTYPE C_fmi3InstantiateCoSimulation;
fmi3EnterInitializationModeTYPE C_fmi3EnterInitializationMode;
fmi3ExitInitializationModeTYPE C_fmi3ExitInitializationMode;
fmi3SetFloat64TYPE C_fmi3SetFloat64;
fmi3GetFloat64TYPE C_fmi3GetFloat64;
fmi3DoStepTYPE C_fmi3DoStep;
fmi3FreeInstanceTYPE C_fmi3FreeInstance;

typedef struct {
    fmi2InstantiateTYPE *instantiate; fmi2SetupExperimentTYPE *setup;
    fmi2EnterInitializationModeTYPE *enter; fmi2ExitInitializationModeTYPE *exit;
    fmi2SetRealTYPE *set; fmi2GetRealTYPE *get; fmi2DoStepTYPE *step; fmi2FreeInstanceTYPE *free;
} Fmi2;

static void logger2(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                    fmi2String category, fmi2String message, ...) {
    (void)env; (void)status; (void)category;
    fprintf(stderr, "%s: %s\n", name, message);
}

static void logger3(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category,
                    fmi3String message) {
    (void)env; (void)status; (void)category;
    fprintf(stderr, "%s\n", message);
}

static const fmi2ValueReference IN[2] = {VR_TAU_R, VR_TAU_L}, OUT[1] = {VR_X};
static const double TAU[2] = {TAU_R, TAU_L};

static int run2(const Fmi2 *f, const char *name, double *x) {
    fmi2CallbackFunctions cb = {logger2, NULL, NULL, NULL, NULL};
    fmi2Component c = f->instantiate(name, fmi2CoSimulation, TOKEN, "", &cb, fmi2False, fmi2False);
    int k;
    if (!c || f->setup(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) || f->enter(c) || f->exit(c))
        return 1;
    for (k = 0; k < N_STEPS; k++)
        if (f->set(c, IN, 2, TAU) || f->step(c, k * STEP_H, STEP_H, fmi2True)) return 1;
    if (f->get(c, OUT, 1, x)) return 1;
    f->free(c);
    return 0;
}

static int run3(double *x) {
    fmi3Boolean event, terminate, early;
    double last;
    int k;
    fmi3Instance c = C_fmi3InstantiateCoSimulation("C", TOKEN, NULL, fmi3False, fmi3False,
                                                   fmi3False, fmi3False, NULL, 0, NULL, logger3,
                                                   NULL);
    if (!c || C_fmi3EnterInitializationMode(c, fmi3False, 0.0, 0.0, fmi3False, 0.0) ||
        C_fmi3ExitInitializationMode(c))
        return 1;
    for (k = 0; k < N_STEPS; k++)
        if (C_fmi3SetFloat64(c, IN, 2, TAU, 2) ||
            C_fmi3DoStep(c, k * STEP_H, STEP_H, fmi3True, &event, &terminate, &early, &last))
            return 1;
    if (C_fmi3GetFloat64(c, OUT, 1, x, 1)) return 1;
    C_fmi3FreeInstance(c);
    return 0;
}

int main(void) {
    Fmi2 a = {A_fmi2Instantiate, A_fmi2SetupExperiment, A_fmi2EnterInitializationMode,
              A_fmi2ExitInitializationMode, A_fmi2SetReal, A_fmi2GetReal, A_fmi2DoStep,
              A_fmi2FreeInstance};
    Fmi2 b = {B_fmi2Instantiate, B_fmi2SetupExperiment, B_fmi2EnterInitializationMode,
              B_fmi2ExitInitializationMode, B_fmi2SetReal, B_fmi2GetReal, B_fmi2DoStep,
              B_fmi2FreeInstance};
    double xa, xb, xc;
    if (run2(&a, "A", &xa) || run2(&b, "B", &xb) || run3(&xc)) return 1;
    printf("%s %.17g %.17g %.17g\n", A_fmi2GetVersion(), xa, xb, xc);
    return 0;
}
"""


def _extract_sources(fmu: Path, dest: Path) -> Path:
    with zipfile.ZipFile(fmu) as zf:
        for name in zf.namelist():
            if name.startswith("sources/"):
                zf.extract(name, dest)
    return dest / "sources"


def _global_symbols(obj: Path) -> list[str]:
    out = subprocess.run(["nm", "-g", "--defined-only", str(obj)], capture_output=True,
                         text=True, check=True).stdout
    return [line.split()[-1] for line in out.splitlines() if line.strip()]


@pytest.mark.skipif(shutil.which("gcc") is None or shutil.which("nm") is None,
                    reason="needs gcc and nm")
def test_two_fmi2_and_one_fmi3_fmu_link_into_one_program(built: BuildResult,
                                                          tmp_path: Path) -> None:
    import fmpy

    headers = Path(fmpy.__file__).parent / "c-code"
    md = read_model_description(str(built.fmus[2]))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    objects = []
    for prefix, version in (("A_", 2), ("B_", 2), ("C_", 3)):
        src = _extract_sources(built.fmus[version], tmp_path / prefix)
        obj = tmp_path / f"{prefix}robot.o"
        subprocess.run(["gcc", "-c", "-O2", "-std=c99", "-Wall", "-Wextra", "-Werror",
                        f"-DFMI{version}_FUNCTION_PREFIX={prefix}", f"-I{src}", f"-I{headers}",
                        str(src / "wmr_robot.c"), "-o", str(obj)], check=True)
        symbols = _global_symbols(obj)
        assert symbols and all(s.startswith(f"{prefix}fmi{version}") for s in symbols), symbols
        assert f"{prefix}fmi{version}DoStep" in symbols
        objects.append(obj)
    (tmp_path / "main.c").write_text(MAIN)
    exe = tmp_path / "three_robots"
    defines = {"TOKEN": f'"{md.guid}"', "VR_X": vr["x"], "VR_TAU_R": vr["tau_r"],
               "VR_TAU_L": vr["tau_l"], "TAU_R": TAU[0], "TAU_L": TAU[1], "N_STEPS": N_STEPS,
               "STEP_H": H}
    subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror",
                    *(f"-D{k}={v}" for k, v in defines.items()), f"-I{headers}",
                    str(tmp_path / "main.c"), *map(str, objects), "-o", str(exe), "-lm"],
                   check=True)
    version, *xs = subprocess.run([str(exe)], capture_output=True, text=True,
                                  check=True).stdout.split()
    assert version == "2.0"
    with FmuPlant(built.fmus[2]) as plant:
        plant.reset(RobotParams(), Pose(0.0, 0.0, 0.0))
        for _ in range(N_STEPS):
            plant.step(*TAU, H)
        expected = plant.outputs()["x"]
    assert expected > 0.1
    assert [float(x) for x in xs] == [expected] * 3


def test_casadi_helpers_getinternal_linkage() -> None:
    code = ("casadi_real casadi_sq(casadi_real x) { return x*x;}\n"
            "CASADI_SYMBOL_EXPORT int wmr_ode(const casadi_real** arg) {\n")
    assert internal_linkage(code).startswith("static casadi_real casadi_sq(")
    with pytest.raises(BuildError, match="external linkage"):
        internal_linkage(code + "double casadi_new_helper(double x) {\n")
