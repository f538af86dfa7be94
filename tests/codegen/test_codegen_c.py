"""Generated headers compiled for real: gcc and arm-none-eabi-gcc, then run against the twin.

For every test model (tests/codegen/test_codegen_models.py) the header must compile warning-free on
the host and for the Cortex-M4; a harness built with AddressSanitizer + UBSan evaluates it on
seeded runs (random walks and jumps, every range corner, one LSB inside and outside every
range, faults and recoveries, absurd codes) and must match ``codegen.fixed`` bit for bit; on
the all-valid runs the float64 model of contract/terms.py, fed the same quantised inputs, must
agree within the bound the generator claims (measured and claimed are printed).
"""

from __future__ import annotations

import itertools
import math
import shutil
import struct
import subprocess
import zlib
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from test_codegen_models import MODELS, model

from thermal_comp import codegen
from thermal_comp.codegen.fixed import FixedModel
from thermal_comp.contract.terms import Term
from thermal_comp.host.fitting import design_matrix

ROOT = Path(__file__).resolve().parents[2]
INCLUDE = ROOT / "firmware" / "include"
RUNTIME = ROOT / "firmware" / "src" / "model_eval.c"
HARNESS = ROOT / "tests" / "codegen" / "test_codegen_harness.c"
CFLAGS = ["-std=c11", "-Wall", "-Wextra", "-Werror", "-pedantic"]
GCC = shutil.which("gcc")
ARM_GCC = shutil.which("arm-none-eabi-gcc")
# float64 evaluation of the reference model (lfilter recursion over a few thousand samples,
# sums of terms up to 1e6 um) is itself off by far less than this; it is 500x below the
# smallest bound any model can claim (the 0.0005 um final rounding).
FLOAT_SLACK_UM = 1e-6

USE_C = """#include "model.h"
uint32_t use_model(void);
uint32_t use_model(void) { return tcm_model_crc32(tcm_model_get()) ^ TCM_MODEL_CRC32; }
"""


def _compile(compiler: str, args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([compiler, *CFLAGS, f"-I{cwd}", f"-I{INCLUDE}", *args], cwd=cwd,
                          capture_output=True, text=True)


def _write_header(tmp: Path, name: str) -> codegen.GeneratedHeader:
    gen = codegen.generate(model(name))
    (tmp / "model.h").write_text(gen.text)
    (tmp / "use.c").write_text(USE_C)
    return gen


# ---- compilation ---------------------------------------------------------------------------

@pytest.mark.skipif(GCC is None or ARM_GCC is None, reason="needs gcc and arm-none-eabi-gcc")
@pytest.mark.parametrize("name", sorted(MODELS))
def test_header_compiles_warning_free_on_host_and_cortex_m4(name, tmp_path):
    _write_header(tmp_path, name)
    for compiler, extra in ((GCC, ["-O2"]), (ARM_GCC, ["-mcpu=cortex-m4", "-mthumb", "-Os"])):
        for src in ("use.c", str(RUNTIME)):
            r = _compile(compiler, [*extra, "-c", src, "-o", "/dev/null"], tmp_path)
            assert r.returncode == 0, f"{compiler} {src}:\n{r.stderr}"


@pytest.mark.skipif(GCC is None, reason="needs gcc")
def test_stale_header_format_is_a_compile_error(tmp_path):
    gen = _write_header(tmp_path, "one_term")
    stale = gen.text.replace("#define TCM_HEADER_FORMAT 7", "#define TCM_HEADER_FORMAT 6")
    assert stale != gen.text
    (tmp_path / "model.h").write_text(stale)
    r = _compile(GCC, ["-c", "use.c", "-o", "/dev/null"], tmp_path)
    assert r.returncode != 0 and "regenerate model.h" in r.stderr


@pytest.mark.skipif(GCC is None, reason="needs gcc")
@pytest.mark.parametrize("edit, message", [
    # A coefficient 2^20 times too big: the compiler's own sum exceeds 2^62 (or overflows).
    (lambda t, g: t.replace(f"INT64_C({g.model.axes[0].terms[0].coef_q})",
                            f"INT64_C({g.model.axes[0].terms[0].coef_q << 20})"),
     "overflow"),
    # A channel range the chip cannot produce.
    (lambda t, g: t.replace("TCM_CH0_MAX_CODE INT32_C(25600)", "TCM_CH0_MAX_CODE INT32_C(300000)"),
     "19-bit"),
    # A term table that disagrees with the axis's term count.
    (lambda t, g: t.replace("TCM_AXIS0_N_TERMS 1u", "TCM_AXIS0_N_TERMS 2u"), "term counts"),
])
def test_static_asserts_reject_a_tampered_header(tmp_path, edit, message):
    """The _Static_asserts re-derive the invariants from the table literals: not tautologies."""
    gen = _write_header(tmp_path, "one_term")
    r = _compile(GCC, ["-c", "use.c", "-o", "/dev/null"], tmp_path)
    assert r.returncode == 0, r.stderr
    tampered = edit(gen.text, gen)
    assert tampered != gen.text
    (tmp_path / "model.h").write_text(tampered)
    r = _compile(GCC, ["-c", "use.c", "-o", "/dev/null"], tmp_path)
    assert r.returncode != 0 and message in r.stderr, r.stderr


# ---- CRC against an independent serialisation ------------------------------------------------

def independent_serialisation(m: dict, fixed_point: dict) -> bytes:
    """docs/fixed-point.md's byte layout, built from the model dict and the integer tables."""
    channels = sorted(m["channels"], key=lambda c: c["channel"])
    aux = sorted(m.get("aux", []), key=lambda a: a["input"])
    out = struct.pack("<IIII", len(channels), len(aux), len(m["axes"]),
                      round(m["sample_period_s"] * 1000))
    for c in channels:
        lo = int(np.ceil(c["min_c"] * 128))
        hi = int(np.floor(c["max_c"] * 128))
        w_lo, w_hi = lo, hi  # docs/fixed-point.md: training range +- 5 % of its span, outwards
        if "trained_min_c" in c:  # exact arithmetic, as the rule is stated
            t_lo, t_hi = Fraction(c["trained_min_c"]), Fraction(c["trained_max_c"])
            margin = (t_hi - t_lo) / 20
            w_lo = min(max(math.floor((t_lo - margin) * 128), lo), hi)
            w_hi = max(min(math.ceil((t_hi + margin) * 128), hi), lo)
        # docs/codegen.md: ceil(max_step_c * 128); without it max(1 degC, 0.1 degC/s * period)
        step_c = Fraction(c["max_step_c"]) if "max_step_c" in c else \
            max(Fraction(1), Fraction(1, 10) * Fraction(m["sample_period_s"]))
        step = max(1, math.ceil(step_c * 128))
        # the stuck limit, 0 (no check) without max_still_samples
        out += struct.pack("<iiiiiBH", lo, hi, w_lo, w_hi, step, {"K": 0, "J": 1}[c["tc_type"]],
                           c.get("max_still_samples", 0))
    for a in aux:
        out += struct.pack("<ii", int(np.ceil(a["min"])), int(np.floor(a["max"])))
    kinds = ["temp", "lag", "rate", "speed", "speed2", "square", "time"]
    sensors = {c["sensor"]: c["channel"] for c in channels}
    aux_index = {a["name"]: a["input"] for a in aux}
    states: dict[tuple[int, int], int] = {}  # one per distinct (channel, a), in table order
    for name, ax in m["axes"].items():
        fp = fixed_point["axes"][name]
        # ceil(max_step_um * 1000) nm; without it 1 um/s * period
        step_um = Fraction(ax["max_step_um"]) if "max_step_um" in ax else \
            Fraction(m["sample_period_s"])
        out += struct.pack("<BBqi", fp["shift"], len(ax["terms"]), fp["intercept_q"],
                           max(1, math.ceil(step_um * 1000)))
        out += _service_bytes(m, ax.get("service"))
        for t, ft in zip(ax["terms"], fp["terms"], strict=True):
            k = t["kind"]
            if k in ("lag", "rate"):
                param = round(t["alpha"] * 2**30)
            elif k == "square":
                param = round(t["ref_c"] * 128)
            elif k == "time":
                param = int(m["time_max_s"] / m["sample_period_s"])
            else:
                param = 0
            src = 0 if k == "time" else (aux_index[t["source"]] if k in ("speed", "speed2")
                                         else sensors[t["source"]])
            state = states.setdefault((src, param), len(states)) if k in ("lag", "rate") else 0
            out += struct.pack("<BBBiq", kinds.index(k), src, state, param, ft["coef_q"])
    return out


def _service_bytes(m: dict, sv: dict | None) -> bytes:
    """docs/fixed-point.md's estimator fields, from docs/service.md's table (issue 42)."""
    if sv is None:
        return struct.pack("<BBIB4q", 0, 0, 0, 0, 0, 0, 0, 0)

    def q(x: Fraction) -> int:  # half away from zero (all non-negative here)
        return math.floor(x + Fraction(1, 2))

    start = (m.get("reference") or {}).get("kind") == "start"
    pmax = q(Fraction(sv["p_max_um2"]) * 10**6 * 256)
    return struct.pack(
        "<BBIB4q", 1, 0 if start else 1, q(Fraction(sv["gate_sigma"]) ** 2 * 256),
        int(sv.get("reopen_after", 3)),  # contract.service.SERVICE_OPTIONAL's default
        q(Fraction(sv["q_um2_per_h"]) * 10**6 * 256 * Fraction(m["sample_period_s"]) / 3600),
        max(1, q(Fraction(sv["probe_noise_um"]) ** 2 * 10**6 * 256)),
        q(Fraction(sv["gate_floor_um"]) ** 2 * 10**6), pmax)


@pytest.mark.parametrize("name", sorted(MODELS))
def test_crc_matches_zlib_over_an_independent_serialisation(name):
    m = model(name)
    gen = codegen.generate(m)
    expected = zlib.crc32(independent_serialisation(m, gen.fixed_point))
    assert gen.crc32 == expected
    assert f"#define TCM_MODEL_CRC32 UINT32_C(0x{expected:08X})" in gen.text


# ---- the harness: C vs twin bit for bit, float vs claimed bound ---------------------------

@dataclass
class Run:
    label: str
    codes: np.ndarray  # int64 [n, channels]
    aux: np.ndarray  # int64 [n, aux]
    valid: np.ndarray  # bool [n, channels], the valid_mask bits
    comparable: bool  # all inputs valid and in range: compare with the float model


def _runs(fm: FixedModel, rng: np.random.Generator) -> list[Run]:
    q = fm.model
    lo = np.array([c.min_code for c in q.channels], dtype=np.int64)
    hi = np.array([c.max_code for c in q.channels], dtype=np.int64)
    alo = np.array([a.min for a in q.aux], dtype=np.int64)
    ahi = np.array([a.max for a in q.aux], dtype=np.int64)
    nch, nax = len(lo), len(alo)

    def uniform(n):
        return (rng.integers(lo, hi + 1, size=(n, nch)), rng.integers(alo, ahi + 1, size=(n, nax)))

    def walk(n):
        start = rng.integers(lo, hi + 1, size=nch)
        steps = rng.normal(0, np.maximum((hi - lo) / 200, 1), size=(n, nch)).cumsum(axis=0)
        codes = np.clip(np.rint(start + steps), lo, hi).astype(np.int64)
        aux = np.clip(np.rint(alo + (ahi - alo) * (0.5 + 0.5 * np.sin(
            np.arange(n)[:, None] / 97.0 + rng.random(nax)))), alo, ahi).astype(np.int64)
        return codes, aux

    all_valid = lambda n: np.ones((n, nch), dtype=bool)  # noqa: E731
    runs = []
    c, a = walk(1500)
    runs.append(Run("walk", c, a, all_valid(1500), True))
    c, a = uniform(1500)
    runs.append(Run("jumps", c, a, all_valid(1500), True))
    # Every corner of the input box, in random order, twice over with repeats.
    corners = list(itertools.product(*[(x, y) for x, y in zip(lo, hi, strict=True)],
                                     *[(x, y) for x, y in zip(alo, ahi, strict=True)]))
    order = rng.permutation(np.repeat(np.arange(len(corners)), max(2, 400 // len(corners))))
    pts = np.array([corners[i] for i in order], dtype=np.int64).reshape(len(order), nch + nax)
    runs.append(Run("corners", pts[:, :nch], pts[:, nch:], all_valid(len(order)), True))
    # One LSB inside and outside every range (flagged valid: out-of-range must still count
    # as a fault), mixed with ordinary values.
    n = 1500
    cand_c = np.stack([lo, lo + 1, hi - 1, hi, lo - 1, hi + 1], axis=1) if nch else None
    cand_a = np.stack([alo, alo + 1, ahi - 1, ahi, alo - 1, ahi + 1], axis=1) if nax else None
    c, a = uniform(n)
    if nch:
        pick = rng.integers(0, 8, size=(n, nch))
        edge = pick < 6
        c = np.where(edge, cand_c[np.arange(nch), np.minimum(pick, 5)], c)
    if nax:
        pick = rng.integers(0, 8, size=(n, nax))
        a = np.where(pick < 6, cand_a[np.arange(nax), np.minimum(pick, 5)], a)
    runs.append(Run("edges", c, a, all_valid(n), False))
    # Faults: channels drop out for random stretches (one is faulted from power-up), so
    # filters cold-start late and freeze; aux occasionally out of range.
    n = 2000
    c, a = walk(n)
    valid = np.ones((n, nch), dtype=bool)
    for ch in range(nch):
        for _ in range(6):
            s = rng.integers(0, n)
            valid[s:s + rng.integers(1, 150), ch] = False
        if ch == 0:
            valid[:120, ch] = False
    if nax:
        bad = rng.random((n, nax)) < 0.03
        a = np.where(bad, ahi + 1 + rng.integers(0, 1000, size=(n, nax)), a)
    runs.append(Run("faults", c, a, valid, False))
    # Absurd inputs flagged valid: any int32 code or aux value must be refused without UB.
    n = 300
    c = rng.integers(-(2**31), 2**31, size=(n, nch), dtype=np.int64)
    c[::3] = np.where(rng.random((len(c[::3]), nch)) < 0.5, -(2**31), 2**31 - 1)
    a = rng.integers(-(2**31), 2**31, size=(n, nax), dtype=np.int64)
    c[1::2], a[1::2] = uniform(len(c[1::2]))
    runs.append(Run("absurd", c, a, rng.random((n, nch)) < 0.9, False))
    # Long enough for the `time` term to saturate (where the model has one).
    if q.time_max_samples is not None and q.time_max_samples < 4000:
        n = q.time_max_samples + 200
        c, a = walk(n)
        runs.append(Run("saturating time", c, a, all_valid(n), True))
    return runs


def _harness_input(runs: list[Run]) -> str:
    lines = ["C"]
    for r in runs:
        lines.append("R")
        masks = (r.valid.astype(np.int64) << np.arange(r.valid.shape[1])).sum(axis=1)
        for i in range(len(masks)):
            lines.append(" ".join(map(str, ["S", int(masks[i]), *r.codes[i].tolist(),
                                            *r.aux[i].tolist()])))
    return "\n".join(lines) + "\n"


def _float_model_um(m: dict, r: Run) -> np.ndarray:
    """contract/terms.py's float model on the quantised inputs (code/128 degC), [n, axes] um."""
    cols = {c["sensor"]: r.codes[:, c["channel"]] / 128.0 for c in m["channels"]}
    cols.update({a["name"]: r.aux[:, a["input"]].astype(float) for a in m.get("aux", [])})
    if not cols:
        cols = {"_": np.zeros(len(r.codes))}
    out = []
    for ax in m["axes"].values():
        terms = [Term.from_json(t) for t in ax["terms"]]
        x = design_matrix(terms, cols, m["sample_period_s"])
        out.append(ax["intercept"] + x @ np.array([t["coef"] for t in ax["terms"]], dtype=float))
    return np.column_stack(out)


@pytest.mark.skipif(GCC is None, reason="needs gcc")
@pytest.mark.parametrize("name", sorted(MODELS))
def test_c_matches_twin_bit_for_bit_and_float_within_bound(name, tmp_path, capsys):
    m = model(name)
    gen = _write_header(tmp_path, name)
    exe = tmp_path / "harness"
    r = _compile(GCC, ["-O1", "-g", "-fsanitize=address,undefined", "-fno-sanitize-recover",
                       str(HARNESS), str(RUNTIME), "-o", str(exe)], tmp_path)
    assert r.returncode == 0, r.stderr

    fm = FixedModel(gen.model)
    runs = _runs(fm, np.random.default_rng(sum(map(ord, name))))
    proc = subprocess.run([str(exe)], input=_harness_input(runs), capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = proc.stdout.splitlines()
    crc_c, crc_macro = (int(x, 16) for x in lines[0].split())
    assert crc_c == crc_macro == zlib.crc32(independent_serialisation(m, gen.fixed_point))
    got = np.array([[int(v) for v in ln.split()] for ln in lines[1:]], dtype=np.int64)
    n_total = sum(len(r.codes) for r in runs)
    assert got.shape == (n_total, 1 + len(gen.model.axes))
    assert n_total >= 7000

    measured = np.zeros(len(gen.model.axes))
    row = 0
    for run in runs:
        n = len(run.codes)
        c_mask, c_out = got[row:row + n, 0], got[row:row + n, 1:]
        row += n
        # twin, vectorised
        out, ok = fm.evaluate_run(run.codes, run.aux, run.valid, return_mask=True)
        mask = (ok.astype(np.int64) << np.arange(ok.shape[1])).sum(axis=1)
        np.testing.assert_array_equal(c_out, out, err_msg=f"{name}/{run.label}: outputs")
        np.testing.assert_array_equal(c_mask, mask, err_msg=f"{name}/{run.label}: masks")
        # twin, one step at a time (the API the firmware tests use)
        fm.reset()
        masks = (run.valid.astype(np.int64) << np.arange(run.valid.shape[1])).sum(axis=1)
        stepped = [fm.step(run.codes[i].tolist(), int(masks[i]), run.aux[i].tolist())
                   for i in range(n)]
        assert [s[0] for s in stepped] == c_out.tolist(), f"{name}/{run.label}: step()"
        assert [s[1] for s in stepped] == c_mask.tolist()
        if run.comparable:
            assert (c_mask == (1 << len(gen.model.axes)) - 1).all()
            ref = _float_model_um(m, run)
            keep = np.arange(n) <= (gen.model.time_max_samples or n)
            err = np.abs(c_out / 1000.0 - ref)[keep].max(axis=0)
            measured = np.maximum(measured, err)

    with capsys.disabled():
        for ax, b, e in zip(gen.model.axes, gen.bounds, measured, strict=True):
            print(f"\n  {name}/{ax.name}: measured worst |C - float| {e:.6f} um, "
                  f"claimed bound {b.bound_um:.6f} um")
    for ax, b, e in zip(gen.model.axes, gen.bounds, measured, strict=True):
        assert e <= b.bound_um + FLOAT_SLACK_UM, f"{name}/{ax.name}: {e} > {b.bound_um}"


def test_crc_covers_the_service_block_as_documented():
    """A model with per-axis service blocks (issue 42): its header's CRC matches the
    documented serialisation, and a changed parameter changes the CRC."""
    m = model("all_kinds")
    m["reference"] = {"kind": "start", "samples": 8}
    for i, ax in enumerate(m["axes"].values()):
        if i % 2 == 0:
            ax["service"] = {"q_um2_per_h": 0.0137, "probe_noise_um": 0.5, "gate_sigma": 4.0,
                             "gate_floor_um": 3.0, "p_max_um2": 6.25}
    gen = codegen.generate(m)
    assert gen.crc32 == zlib.crc32(independent_serialisation(m, gen.fixed_point))
    next(iter(m["axes"].values()))["service"]["gate_sigma"] = 5.0
    assert codegen.generate(m).crc32 != gen.crc32
