"""codegen numbers: generation time, the Python twin's replay speed, the C footprint.

The twin must replay a 24 h run at 1 s (86,400 samples) in about a second for the HIL; the
footprint answers "how much flash/RAM does the model cost on the STM32F405".
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.goal import INFO, goal
from thermal_comp import codegen
from thermal_comp.codegen.fixed import FixedModel
from thermal_comp.contract.terms import make_lag, make_rate, make_speed, make_temp

ROOT = Path(__file__).resolve().parents[1]
N_SAMPLES = 86_400


def _model() -> dict:
    """A model of the size `host train` produces: 3 axes x 4 terms over 6 channels."""
    chans = [{"channel": i, "sensor": f"T{i + 1:02d}", "tc_type": "K", "min_c": -40.0,
              "max_c": 200.0} for i in range(6)]
    m = {"schema": "thermal-model/1", "sample_period_s": 1.0, "channels": chans,
         "aux": [{"input": 0, "name": "spindle_rpm", "min": 0.0, "max": 12000.0}],
         "time_max_s": 604800.0, "axes": {}}
    for a, axis in enumerate(("dx_um", "dy_um", "dz_um")):
        s = [f"T{2 * a + 1:02d}", f"T{2 * a + 2:02d}"]
        terms = [make_temp(s[0]), make_lag(s[1], 1800.0 * (a + 1), 1.0),
                 make_rate(s[0], 600.0, 1.0), make_speed("spindle_rpm")]
        coefs = [2.1 - a, -1.3, 3.0, 1e-4]
        m["axes"][axis] = {"unit": "um", "intercept": -0.5 * a,
                           "terms": [{**t.to_json(), "coef": c} for t, c in zip(terms, coefs,
                                                                               strict=True)]}
    return m


def _arm_sizes(gen: codegen.GeneratedHeader) -> tuple[int, int] | None:
    arm = shutil.which("arm-none-eabi-gcc")
    size = shutil.which("arm-none-eabi-size")
    if not arm or not size:
        return None
    with tempfile.TemporaryDirectory() as d:
        (Path(d) / "model.h").write_text(gen.text)
        (Path(d) / "use.c").write_text('#include "model.h"\n'
                                       "const void *use(void) { return tcm_model_get(); }\n")
        flags = ["-std=c11", "-Os", "-mcpu=cortex-m4", "-mthumb", f"-I{d}",
                 f"-I{ROOT / 'firmware' / 'include'}", "-c"]
        subprocess.run([arm, *flags, str(ROOT / "firmware" / "src" / "model_eval.c"), "-o",
                        f"{d}/rt.o"], check=True)
        subprocess.run([arm, *flags, f"{d}/use.c", "-o", f"{d}/use.o"], check=True)
        out = subprocess.run([size, f"{d}/rt.o", f"{d}/use.o"], check=True,
                             capture_output=True, text=True).stdout.splitlines()
        # text includes .rodata for these objects (tables and strings)
        return int(out[1].split()[0]), int(out[2].split()[0])


def run() -> list[dict]:
    m = _model()
    t0 = time.perf_counter()
    for _ in range(20):
        gen = codegen.generate(m)
    gen_ms = (time.perf_counter() - t0) / 20 * 1000

    fm = FixedModel(gen.model)
    rng = np.random.default_rng(0)
    codes = np.clip(2560 + rng.normal(0, 20, size=(N_SAMPLES, 6)).cumsum(axis=0),
                    -5120, 25600).astype(np.int64)
    aux = rng.integers(0, 12001, size=(N_SAMPLES, 1))
    t0 = time.perf_counter()
    fm.evaluate_run(codes, aux)
    run_s = time.perf_counter() - t0

    n_step = 5000
    fm.reset()
    t0 = time.perf_counter()
    for i in range(n_step):
        fm.step(codes[i].tolist(), None, aux[i].tolist())
    step_us = (time.perf_counter() - t0) / n_step * 1e6

    rows = [
        {"name": "generate() 3 axes x 4 terms", "value": gen_ms, "unit": "ms", "goal": INFO},
        {"name": f"twin evaluate_run, {N_SAMPLES} samples", "value": run_s, "unit": "s",
         "target": "< 1 s", "goal": goal("<", 1),
         "detail": "3 axes, 6 channels, 3 lag/rate states"},
        {"name": "twin step() per sample", "value": step_us, "unit": "us", "goal": INFO},
        {"name": "worst error bound over axes", "unit": "um", "target": "<= 0.01",
         "goal": goal("<=", 0.01),
         "value": max(b.bound_um for b in gen.bounds)},
    ]
    sizes = _arm_sizes(gen)
    if sizes:
        rows += [
            {"name": "Cortex-M4 -Os runtime (model_eval.o) text", "value": sizes[0],
             "unit": "bytes", "goal": INFO},
            {"name": "Cortex-M4 model tables + strings (12 terms)", "value": sizes[1],
             "unit": "bytes", "goal": INFO, "detail": "flash; RAM: one tcm_state_t = 264 bytes"},
        ]
    return rows
