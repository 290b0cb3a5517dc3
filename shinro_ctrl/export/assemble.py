"""The exported folder's files from an estimator part, a controller part and the recorded data.

:func:`assemble` returns ``{file name: text}``: ``NAME.h`` (the documented API), ``NAME_internal.h``,
``NAME.c`` (``init``/``reset``/``set_reference``/``step`` around the parts), ``NAME_est.c``,
``NAME_ctl.c`` and the parts' extra sources, ``NAME_test.c`` (replays ``NAME_data.txt`` and times the
step), ``Makefile``, ``CMakeLists.txt``, ``README.md``, ``scenario.toml`` and ``export.json`` (versions,
scenario hash, every file's SHA-256). Everything is a pure function of its inputs: no time stamps,
sorted keys, ``%.17g`` numbers, so the same scenario gives byte-identical folders.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass

import numpy as np

from shinro_ctrl.export.parts import Part, c_number, fill, format_array

__all__ = ["DATA_FORMAT", "EXPORT_FORMAT", "Recording", "Unit", "assemble", "data_hash"]

EXPORT_FORMAT = "shinro_ctrl export 1"
DATA_FORMAT = "shinro_ctrl_export_data 1"

#: Status codes (bit flags) of every exported step, in the header; a part returns an OR of them.
STATUS_CODES: tuple[tuple[str, int, str], ...] = (
    ("OK", 0, "the input was computed normally"),
    ("INPUT_CLAMPED", 1, "an input saturation bound was active (u_out lies on it)"),
    ("SOLVER_MAX_ITER", 2, "an iterative solver stopped at its iteration limit (u_out is its last iterate)"),
    ("PLAN_FINISHED", 4, "a plan-tracking controller is past its plan and applies its final law"),
    ("ERROR", 16, "mask: any status >= this is an error; u_out then repeats the previous input"),
    ("NONFINITE_MEASUREMENT", 16, "the measurement holds NaN or inf: nothing was updated"),
    ("NONFINITE_RESULT", 32, "an internal value overflowed (state far outside the model's range): reset"),
    ("BAD_ARGUMENT", 64, "a NULL pointer, or a non-finite reference or initial estimate"),
    ("QP_INFEASIBLE", 128, "the MPC's QP has no feasible point at this state (certified by the active-set solver)"),
)


@dataclass(frozen=True)
class Recording:
    """Closed-loop data recorded from the Python controller, replayed by the test program.

    Attributes:
        label: Where it came from (``standalone``, ``mujoco``, ...).
        x_hat0: The estimate the loop started the estimator from ``(n,)``.
        y: Measurements ``(T, p)``.
        ref: References ``(T, n)``.
        u: The Python controller's inputs ``(T, m)``.
    """

    label: str
    x_hat0: np.ndarray
    y: np.ndarray
    ref: np.ndarray
    u: np.ndarray


@dataclass(frozen=True)
class Unit:
    """Everything :func:`assemble` writes from.

    Attributes:
        name: C name.
        estimator, controller: The two parts.
        n, m, p: States, inputs, measurements.
        dt: Sample time [s].
        x_hat0: Default initial estimate ``(n,)`` (``NAME_reset(ws, NULL)``).
        u_init: The input assumed applied before the first step ``(m,)``.
        ref0: The reference after ``NAME_init`` ``(n,)``.
        measured: Names of the measured states (in the order of ``y``).
        state_names, input_names: Names.
        scenario_text: The scenario file's text; scenario_name its file name.
        versions: Package versions.
        tolerance: Agreement the test program demands.
        design: The controller's ``x0``, ``u0``, ``u_min``, ``u_max`` (lists or None), recorded in ``export.json``
            so that the software-in-the-loop controller reports the same operating point and bounds.
    """

    name: str
    estimator: Part
    controller: Part
    n: int
    m: int
    p: int
    dt: float
    x_hat0: np.ndarray
    u_init: np.ndarray
    ref0: np.ndarray
    measured: tuple[str, ...]
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    scenario_text: str
    scenario_name: str
    versions: dict[str, str]
    tolerance: float = 1e-9
    design: dict[str, list[float] | None] | None = None

    @property
    def scenario_hash(self) -> str:
        """SHA-256 of the scenario file's text."""
        return hashlib.sha256(self.scenario_text.encode("utf-8")).hexdigest()


def data_hash(unit: Unit) -> str:
    """SHA-256 over the scenario hash and every constant the C holds: what ties recorded data to its code."""
    h = hashlib.sha256()
    h.update(unit.scenario_hash.encode())
    for part in (unit.estimator, unit.controller):
        h.update(part.kind.encode())
        h.update(part.tables_text(unit.name).encode())
    for arr in (unit.x_hat0, unit.u_init, unit.ref0):
        h.update(format_array(arr).encode())
    h.update(c_number(unit.dt).encode())
    return h.hexdigest()


def _sub(text: str, name: str) -> str:
    return fill(text, name)


def _header(u: Unit, dhash: str) -> str:
    N = u.name
    U = N.upper()
    codes = "\n".join(f"#define {U}_{c} {v} /* {doc} */" for c, v, doc in STATUS_CODES)
    fields = (
        "\n".join(f.declaration(part.tag) for part in (u.estimator, u.controller) for f in part.fields)
        or "    /* (the parts keep no fields of their own) */"
    )
    xh = max(u.estimator.out_dim, u.n)
    return f"""/* {N}.h: the C API of the exported controller "{N}" (generated by shinro_ctrl export; do not edit).
 *
 * Estimator:  {u.estimator.kind}: {u.estimator.summary}
 * Controller: {u.controller.kind}: {u.controller.summary}
 * Scenario:   {u.scenario_name} (sha256 {u.scenario_hash})
 *
 * Call {N}_step once per sample time ({U}_DT s) with the measurement y ({U}_NY values, SI units, in the order
 * {", ".join(u.measured)}); it writes the input u_out ({U}_NU values: {", ".join(u.input_names)}) to apply
 * until the next call. The workspace holds every buffer (no heap); place it where you like (static, stack).
 *
 *   static {N}_workspace ws;
 *   {N}_init(&ws);                         // zeroes, sets the default reference and resets
 *   {N}_set_reference(&ws, r);             // optional: the reference state ({U}_NX values)
 *   for (;;) {{ status = {N}_step(&ws, y, u); apply(u); wait_for_next_sample(); }}
 *
 * Not reentrant per workspace: one workspace per thread of control.
 */
#ifndef {U}_H
#define {U}_H

#ifdef __cplusplus
extern "C" {{
#endif

#define {U}_NX {u.n} /* states ({", ".join(u.state_names)}) */
#define {U}_NU {u.m} /* inputs */
#define {U}_NY {u.p} /* measurements */
#define {U}_NXHAT {xh} /* entries of the estimate x_hat */
#define {U}_DT {c_number(u.dt)} /* sample time [s] */

/* Status codes of {N}_step (bit flags: test with &; an error is status >= {U}_ERROR). */
{codes}

/* Every buffer of the controller and its estimator. */
typedef struct {{
{fields}
    double ref[{u.n}]; /* the reference state (set by {N}_set_reference) */
    double u_prev[{u.m}]; /* the input returned by the last step (applied over the last sample) */
    double x_hat[{xh}]; /* the estimate of the last step */
}} {N}_workspace;

/* Zero the workspace, set the default reference (the scenario's at t = 0) and reset. Returns a status. */
int {N}_init({N}_workspace *ws);

/* Restart: the estimator from x_hat0 ({U}_NX values; NULL: the exported initial estimate), the controller's
 * memory (integrators, time index) emptied, the previous input set to the operating input. Returns a status. */
int {N}_reset({N}_workspace *ws, const double *x_hat0);

/* The reference state r ({U}_NX values) used from the next step on. Returns a status. */
int {N}_set_reference({N}_workspace *ws, const double *ref);

/* One sample: estimate from y ({U}_NY values) and the previous input, then the input u_out ({U}_NU values).
 * Returns an OR of the status codes above. */
int {N}_step({N}_workspace *ws, const double *y, double *u_out);

/* sizeof({N}_workspace), for callers that cannot see the struct (a foreign-function interface). */
unsigned long {N}_workspace_size(void);

/* SHA-256 (hex) of the scenario and of every constant compiled in: the test program refuses data recorded
 * for other constants. */
const char *{N}_data_hash(void);

/* "{dhash}" */
#define {U}_DATA_HASH "{dhash}"

#ifdef __cplusplus
}}
#endif

#endif /* {U}_H */
"""


def _internal(u: Unit) -> str:
    N = u.name
    return f"""/* {N}_internal.h: declarations shared by the sources of "{N}" (not part of the API). */
#ifndef {N.upper()}_INTERNAL_H
#define {N.upper()}_INTERNAL_H
#include <math.h>
#include <string.h>
#include "{N}.h"

void {N}_est_reset({N}_workspace *ws, const double *x_hat0);
int {N}_est_update({N}_workspace *ws, const double *y, const double *u_prev, double *x_hat);
void {N}_ctl_reset({N}_workspace *ws);
int {N}_ctl_step({N}_workspace *ws, const double *x_hat, const double *ref, double *u);

#endif
"""


def _main_c(u: Unit, dhash: str) -> str:
    N = u.name
    U = N.upper()
    xh = max(u.estimator.out_dim, u.n)
    return f"""/* {N}.c: the public API of "{N}" around its estimator ({N}_est.c) and controller ({N}_ctl.c). */
#include "{N}_internal.h"

/* The exported initial estimate (NX), the input assumed before the first step (NU), the default reference (NX). */
static const double {N}_x_hat0[{u.n}] = {format_array(u.x_hat0)};
static const double {N}_u_init[{u.m}] = {format_array(u.u_init)};
static const double {N}_ref0[{u.n}] = {format_array(u.ref0)};

static int {N}_all_finite(const double *v, int k) {{
    int i;
    for (i = 0; i < k; ++i) {{
        if (!isfinite(v[i])) {{
            return 0;
        }}
    }}
    return 1;
}}

const char *{N}_data_hash(void) {{
    return {U}_DATA_HASH;
}}

unsigned long {N}_workspace_size(void) {{
    return (unsigned long)sizeof({N}_workspace);
}}

int {N}_reset({N}_workspace *ws, const double *x_hat0) {{
    if (ws == NULL) {{
        return {U}_BAD_ARGUMENT;
    }}
    if (x_hat0 == NULL) {{
        x_hat0 = {N}_x_hat0;
    }} else if (!{N}_all_finite(x_hat0, {u.n})) {{
        return {U}_BAD_ARGUMENT;
    }}
    {N}_est_reset(ws, x_hat0);
    {N}_ctl_reset(ws);
    memcpy(ws->u_prev, {N}_u_init, sizeof ws->u_prev);
    memset(ws->x_hat, 0, sizeof ws->x_hat);
    memcpy(ws->x_hat, x_hat0, {u.n} * sizeof(double));
    return {U}_OK;
}}

int {N}_init({N}_workspace *ws) {{
    if (ws == NULL) {{
        return {U}_BAD_ARGUMENT;
    }}
    memset(ws, 0, sizeof *ws);
    memcpy(ws->ref, {N}_ref0, sizeof ws->ref);
    return {N}_reset(ws, NULL);
}}

int {N}_set_reference({N}_workspace *ws, const double *ref) {{
    if (ws == NULL || ref == NULL || !{N}_all_finite(ref, {u.n})) {{
        return {U}_BAD_ARGUMENT;
    }}
    memcpy(ws->ref, ref, sizeof ws->ref);
    return {U}_OK;
}}

int {N}_step({N}_workspace *ws, const double *y, double *u_out) {{
    double x_hat[{xh}];
    double u[{u.m}];
    int status;
    if (ws == NULL || y == NULL || u_out == NULL) {{
        return {U}_BAD_ARGUMENT;
    }}
    if (!{N}_all_finite(y, {u.p})) {{
        memcpy(u_out, ws->u_prev, sizeof ws->u_prev);
        return {U}_NONFINITE_MEASUREMENT;
    }}
    status = {N}_est_update(ws, y, ws->u_prev, x_hat);
    if (status < {U}_ERROR) {{
        status |= {N}_ctl_step(ws, x_hat, ws->ref, u);
    }}
    if (status < {U}_ERROR && !{N}_all_finite(u, {u.m})) {{
        status |= {U}_NONFINITE_RESULT;
    }}
    if (status >= {U}_ERROR) {{
        memcpy(u_out, ws->u_prev, sizeof ws->u_prev);
        return status;
    }}
    memcpy(ws->x_hat, x_hat, sizeof ws->x_hat);
    memcpy(ws->u_prev, u, sizeof ws->u_prev);
    memcpy(u_out, u, sizeof u);
    return status;
}}
"""


def _test_c(u: Unit) -> str:
    N = u.name
    U = N.upper()
    return f"""/* {N}_test.c: replay the closed-loop data recorded from the Python controller and time the step.
 *
 *   ./{N}_test {N}_data.txt [--time]
 *
 * Checks, for every recorded step, |u_C - u_Python| <= tol * max(1, |u_Python|) (relative, absolute near zero);
 * refuses data recorded for other constants (stale folder). Prints "agreement ..." and, with --time,
 * "timing median_ns=..." (median over repeated passes of the wall time per step). Exit status 0 when
 * everything agrees, 1 on a disagreement, 2 on unreadable or stale data. (This program may use the heap.)
 */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "{N}.h"

typedef struct {{
    char label[64];
    long steps;
    double x_hat0[{U}_NX];
    double *y, *ref, *u;
}} run_t;

static int read_doubles(FILE *f, double *v, long k) {{
    long i;
    for (i = 0; i < k; ++i) {{
        if (fscanf(f, "%lf", &v[i]) != 1) {{
            return 0;
        }}
    }}
    return 1;
}}

static double now_s(void) {{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}}

static int cmp_double(const void *a, const void *b) {{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}}

int main(int argc, char **argv) {{
    FILE *f;
    char word[128], hash[128];
    int ny, nx, nu, nruns, r, fmt;
    long k, total = 0, clamped = 0, errors = 0, bad = 0;
    double tol, worst = 0.0;
    run_t *runs;
    static {N}_workspace ws;
    if (argc < 2) {{
        fprintf(stderr, "usage: %s {N}_data.txt [--time]\\n", argv[0]);
        return 2;
    }}
    f = fopen(argv[1], "r");
    if (f == NULL) {{
        fprintf(stderr, "cannot open %s\\n", argv[1]);
        return 2;
    }}
    if (fscanf(f, "%127s %d", word, &fmt) != 2 || strcmp(word, "shinro_ctrl_export_data") != 0 || fmt != 1 ||
        fscanf(f, "%127s %127s", word, hash) != 2 || strcmp(word, "hash") != 0) {{
        fprintf(stderr, "%s: not a shinro_ctrl export data file\\n", argv[1]);
        return 2;
    }}
    if (strcmp(hash, {N}_data_hash()) != 0) {{
        fprintf(stderr, "stale: %s was recorded for data hash %s but this code holds %s (re-export the scenario)\\n",
                argv[1], hash, {N}_data_hash());
        return 2;
    }}
    if (fscanf(f, "%127s %d %d %d", word, &ny, &nx, &nu) != 4 || ny != {U}_NY || nx != {U}_NX || nu != {U}_NU ||
        fscanf(f, "%127s %lf %127s %d", word, &tol, hash, &nruns) != 4 || nruns < 1) {{
        fprintf(stderr, "%s: dimensions or header do not match the compiled code\\n", argv[1]);
        return 2;
    }}
    runs = (run_t *)calloc((size_t)nruns, sizeof(run_t));
    for (r = 0; r < nruns; ++r) {{
        run_t *R = &runs[r];
        if (fscanf(f, "%127s %63s %ld", word, R->label, &R->steps) != 3 || R->steps < 1 ||
            !read_doubles(f, R->x_hat0, {U}_NX)) {{
            fprintf(stderr, "%s: bad run header\\n", argv[1]);
            return 2;
        }}
        R->y = (double *)malloc((size_t)R->steps * {U}_NY * sizeof(double));
        R->ref = (double *)malloc((size_t)R->steps * {U}_NX * sizeof(double));
        R->u = (double *)malloc((size_t)R->steps * {U}_NU * sizeof(double));
        for (k = 0; k < R->steps; ++k) {{
            if (!read_doubles(f, R->y + k * {U}_NY, {U}_NY) || !read_doubles(f, R->ref + k * {U}_NX, {U}_NX) ||
                !read_doubles(f, R->u + k * {U}_NU, {U}_NU)) {{
                fprintf(stderr, "%s: run %s is truncated at step %ld\\n", argv[1], R->label, k);
                return 2;
            }}
        }}
    }}
    fclose(f);
    {N}_init(&ws);
    for (r = 0; r < nruns; ++r) {{
        run_t *R = &runs[r];
        {N}_reset(&ws, R->x_hat0);
        for (k = 0; k < R->steps; ++k) {{
            double u[{U}_NU];
            int i, st;
            {N}_set_reference(&ws, R->ref + k * {U}_NX);
            st = {N}_step(&ws, R->y + k * {U}_NY, u);
            if (st >= {U}_ERROR) {{
                ++errors;
            }}
            if (st & {U}_INPUT_CLAMPED) {{
                ++clamped;
            }}
            for (i = 0; i < {U}_NU; ++i) {{
                double p = R->u[k * {U}_NU + i], e = fabs(u[i] - p) / (fabs(p) > 1.0 ? fabs(p) : 1.0);
                if (!(e <= tol)) {{
                    if (bad < 5) {{
                        fprintf(stderr, "disagree: run %s step %ld input %d: C %.17g Python %.17g\\n", R->label, k, i,
                                u[i], p);
                    }}
                    ++bad;
                }}
                if (e > worst || e != e) {{
                    worst = e;
                }}
            }}
        }}
        total += R->steps;
    }}
    printf("agreement steps=%ld max_rel_err=%.3e clamped=%ld errors=%ld disagreements=%ld tol=%.1e\\n", total, worst,
           clamped, errors, bad, tol);
    if (argc > 2 && strcmp(argv[2], "--time") == 0) {{
        double times[401], t_start = now_s();
        int reps = 0;
        while (reps < 401 && (reps < 11 || now_s() - t_start < 0.5)) {{
            double t0 = now_s();
            long steps = 0;
            for (r = 0; r < nruns; ++r) {{
                run_t *R = &runs[r];
                double u[{U}_NU];
                {N}_reset(&ws, R->x_hat0);
                {N}_set_reference(&ws, R->ref);
                for (k = 0; k < R->steps; ++k) {{
                    if (k > 0 && memcmp(R->ref + k * {U}_NX, R->ref + (k - 1) * {U}_NX, {U}_NX * sizeof(double))) {{
                        {N}_set_reference(&ws, R->ref + k * {U}_NX);
                    }}
                    {N}_step(&ws, R->y + k * {U}_NY, u);
                }}
                steps += R->steps;
            }}
            times[reps++] = (now_s() - t0) / (double)steps;
        }}
        qsort(times, (size_t)reps, sizeof(double), cmp_double);
        printf("timing median_ns=%.2f passes=%d\\n", 1e9 * times[reps / 2], reps);
    }}
    for (r = 0; r < nruns; ++r) {{
        free(runs[r].y);
        free(runs[r].ref);
        free(runs[r].u);
    }}
    free(runs);
    return bad == 0 && errors == 0 ? 0 : 1;
}}
"""


def _c_sources(u: Unit) -> list[str]:
    N = u.name
    extra = [_sub(fname, N) for part in (u.estimator, u.controller) for fname, _ in part.sources]
    return [f"{N}.c", f"{N}_est.c", f"{N}_ctl.c", *sorted(x for x in extra if x.endswith(".c"))]


def _makefile(u: Unit) -> str:
    N = u.name
    srcs = " ".join(_c_sources(u))
    return f"""# Build "{N}": the controller as a static and a shared library, and its test program. C99, libm only.
#   make            build everything (CFLAGS=-O2 by default)
#   make check      replay the recorded Python data and compare
#   make time       the same, and time the step
CC ?= cc
CFLAGS ?= -O2
WARN = -std=c99 -Wall -Wextra -Werror -pedantic
SRC = {srcs}
OBJ = $(SRC:.c=.o)
HDR = $(wildcard *.h)

all: lib{N}.a lib{N}.so {N}_test

%.o: %.c $(HDR)
\t$(CC) $(WARN) $(CFLAGS) -fPIC -c $< -o $@

lib{N}.a: $(OBJ)
\tar rcs $@ $(OBJ)

lib{N}.so: $(OBJ)
\t$(CC) -shared -o $@ $(OBJ) -lm

{N}_test: {N}_test.c lib{N}.a
\t$(CC) $(WARN) $(CFLAGS) -o $@ {N}_test.c lib{N}.a -lm

check: {N}_test
\t./{N}_test {N}_data.txt

time: {N}_test
\t./{N}_test {N}_data.txt --time

clean:
\trm -f $(OBJ) lib{N}.a lib{N}.so {N}_test

.PHONY: all check time clean
"""


def _cmake(u: Unit) -> str:
    N = u.name
    srcs = " ".join(_c_sources(u))
    return f"""# Build "{N}" with CMake: the library {N} (static) and the test {N}_test (ctest runs the replay).
cmake_minimum_required(VERSION 3.10)
project({N} C)
set(CMAKE_C_STANDARD 99)
set(CMAKE_C_STANDARD_REQUIRED ON)
set(CMAKE_C_EXTENSIONS OFF)
add_library({N} STATIC {srcs})
target_include_directories({N} PUBLIC ${{CMAKE_CURRENT_SOURCE_DIR}})
if(CMAKE_C_COMPILER_ID MATCHES "GNU|Clang")
  target_compile_options({N} PRIVATE -Wall -Wextra -pedantic)
endif()
find_library(M_LIB m)
if(M_LIB)
  target_link_libraries({N} PUBLIC ${{M_LIB}})
endif()
add_executable({N}_test {N}_test.c)
target_link_libraries({N}_test {N})
enable_testing()
add_test(NAME {N}_replay COMMAND {N}_test ${{CMAKE_CURRENT_SOURCE_DIR}}/{N}_data.txt)
"""


def _data(u: Unit, dhash: str, recordings: list[Recording]) -> str:
    def row(*vecs: np.ndarray) -> str:
        return " ".join(c_number(v) for vec in vecs for v in np.asarray(vec).reshape(-1))

    lines = [
        DATA_FORMAT,
        f"hash {dhash}",
        f"dims {u.p} {u.n} {u.m}",
        f"tolerance {c_number(u.tolerance)} runs {len(recordings)}",
    ]
    for rec in recordings:
        lines.append(f"run {rec.label} {rec.y.shape[0]} {row(rec.x_hat0)}")
        lines.extend(row(rec.y[k], rec.ref[k], rec.u[k]) for k in range(rec.y.shape[0]))
    return "\n".join(lines) + "\n"


def _readme(u: Unit, dhash: str, recordings: list[Recording]) -> str:
    N = u.name
    U = N.upper()
    steps = sum(r.y.shape[0] for r in recordings)
    loops = ", ".join(f"{r.label} ({r.y.shape[0]} steps)" for r in recordings)
    versions = "\n".join(f"- {k} {v}" for k, v in sorted(u.versions.items()))
    codes = "\n".join(f"| `{U}_{c}` | {v} | {doc} |" for c, v, doc in STATUS_CODES)
    return f"""# {N}: exported controller

Generated by `shinro-ctrl export` from the scenario `{u.scenario_name}` (`scenario.toml` here;
SHA-256 `{u.scenario_hash}`). Dependency-free C99: only `libm`, no heap, no Python, no CasADi.

- Estimator: **{u.estimator.kind}**: {u.estimator.summary}
- Controller: **{u.controller.kind}**: {u.controller.summary}
- Sample time: {c_number(u.dt)} s: call `{N}_step` once per sample.
- Measurement `y` ({u.p}): {", ".join(u.measured)} (SI units: m, rad, m/s, rad/s, as the plant's states).
- Input `u` ({u.m}): {", ".join(u.input_names)} (SI units: N, N·m).
- Reference (`{N}_set_reference`, {u.n} values): {", ".join(u.state_names)}.

## API (`{N}.h`)

```c
static {N}_workspace ws;                 /* every buffer; no heap */
{N}_init(&ws);                           /* default reference, reset */
{N}_reset(&ws, x_hat0);                  /* x_hat0: NX values, or NULL for the exported initial estimate */
{N}_set_reference(&ws, r);               /* NX values */
int status = {N}_step(&ws, y, u_out);    /* once per {c_number(u.dt)} s */
```

| status | value | meaning |
|---|---|---|
{codes}

The step is the scenario's output-feedback loop exactly as the Python simulation runs it: the estimator
takes `y` and the input returned by the previous step (after a reset, the operating input), then the
controller maps the estimate and the reference to `u_out`.

{u.estimator.details}

{u.controller.details}

## Build, run, verify

```sh
make            # lib{N}.a, lib{N}.so and {N}_test (gcc -std=c99 -Wall -Wextra -Werror -pedantic)
make check      # replays {N}_data.txt: {steps} closed-loop steps recorded from the Python controller
make time       # the same, and the median step time on this machine
```

or `cmake -S . -B build && cmake --build build && (cd build && ctest)`. Add the `.c` files to your own build
as they are; compile them without `-ffast-math` (it would change the arithmetic the test checks).

The recorded data ({loops}) holds each step's measurement, reference and the Python controller's input;
the test program demands `|u_C − u_Python| ≤ {u.tolerance:g} · max(1, |u_Python|)` at every step, and
refuses data recorded for other constants (the data hash `{dhash[:16]}…` covers the scenario and every
table compiled in).

## Versions

{versions}

Software in the loop: `shinro_ctrl.export.load("<this folder>")` returns a controller that runs this code
through `ctypes`; a scenario's `[controller] type = "Exported"`, `path = "<this folder>"` runs it in
either simulation loop.
"""


def assemble(unit: Unit, recordings: list[Recording]) -> dict[str, str]:
    """Every file of the exported folder: ``{file name: text}`` (see the module docstring)."""
    N = unit.name
    dhash = data_hash(unit)
    files: dict[str, str] = {
        f"{N}.h": _header(unit, dhash),
        f"{N}_internal.h": _internal(unit),
        f"{N}.c": _main_c(unit, dhash),
        f"{N}_est.c": unit.estimator.source(N),
        f"{N}_ctl.c": unit.controller.source(N),
        f"{N}_test.c": _test_c(unit),
        f"{N}_data.txt": _data(unit, dhash, recordings),
        "Makefile": _makefile(unit),
        "CMakeLists.txt": _cmake(unit),
        "README.md": _readme(unit, dhash, recordings),
        "scenario.toml": unit.scenario_text if unit.scenario_text.endswith("\n") else unit.scenario_text + "\n",
    }
    for part in (unit.estimator, unit.controller):
        for fname, text in part.sources:
            files[_sub(fname, N)] = _sub(text, N)
    manifest = {
        "format": EXPORT_FORMAT,
        "name": N,
        "scenario": {"file": unit.scenario_name, "sha256": unit.scenario_hash},
        "data_hash": dhash,
        "estimator": unit.estimator.kind,
        "controller": unit.controller.kind,
        "dims": {"n": unit.n, "m": unit.m, "p": unit.p},
        "dt": unit.dt,
        "measured": list(unit.measured),
        "state_names": list(unit.state_names),
        "input_names": list(unit.input_names),
        "recorded": {r.label: int(r.y.shape[0]) for r in recordings},
        "tolerance": unit.tolerance,
        "versions": dict(sorted(unit.versions.items())),
        "design": dict(sorted((unit.design or {}).items())),
        "files": {k: hashlib.sha256(v.encode("utf-8")).hexdigest() for k, v in sorted(files.items())},
    }
    files["export.json"] = json.dumps(manifest, indent=2, sort_keys=True) + "\n"
    return dict(sorted(files.items()))
