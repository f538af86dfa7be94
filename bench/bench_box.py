"""What the default model costs the box: instructions per model step, flash and RAM (issue 13).

For one representative case per accuracy source (bench/bench_accuracy.py), the default model
(``train_model`` defaults, ``reference=`` when it takes one) is generated into a header and
built for the STM32F405:
- flash (text + data) and RAM (data + bss, the 1 KiB stack included) of the BOARD=stm32f405
  image from arm-none-eabi-size, against the budget of 16 KiB / 4 KiB;
- Cortex-M4 instructions per model step: the BOARD=qemu_uartfeed image (same compiler and flags,
  samples fed over USART2) replays the first ``N_SAMPLES`` samples of the case's test run under
  ``qemu-system-arm -singlestep -d exec,nochain -dfilter <tcm_step and its callees>`` (one trace
  line per executed guest instruction, PLATFORM.md); the lines divided by the number of entries
  into ``tcm_step`` (the model evaluation, firmware/src/model_eval.c). Measured for the shipped
  ``-Os`` build and for ``-O3`` (BOX_CFLAGS=-O3); a 5-term int64 dot product needs about 21
  at -O3 (the physical floor), 36 at -Os.

    python -m bench box
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.goal import INFO, goal

ROOT = Path(__file__).resolve().parents[1]
N_SAMPLES = 30
MODEL_FUNCTION = "tcm_step"
FLASH_BUDGET = 16 * 1024
RAM_BUDGET = 4 * 1024
DOT5_FLOOR_O3 = 21
TRACE_PC = re.compile(rb"^Trace \d+: 0x[0-9a-f]+ \[[0-9a-f]+/([0-9a-f]+)/")


def _log(msg: str) -> None:
    print(f"[box] {msg}", file=sys.stderr, flush=True)


def representative_cases():
    """The sim_dev and FL jobs whose default model is measured (the sim one is written)."""
    from bench import bench_accuracy as acc

    dev = next(j for j in acc.dev_jobs(big=False) if j.group.endswith("machine11 S1"))
    fl = next(j for j in acc.fl_jobs() if j.group == "FL cycle 4 out")
    return dev, fl


def train_default(job) -> dict:
    from bench import bench_accuracy as acc
    from thermal_comp.host.train import train_model

    runs = [acc._load(s, job.targets) for s in job.train]
    return train_model(runs, list(job.targets), aux=acc.AUX,
                       **acc.train_kwargs(job.reference, job.bending, job.targets))


def head_csv(src: str, dst: Path, n: int, start_s: float | None = None) -> Path:
    """The first ``n`` samples of a run (from ``start_s``) as a CSV of its own."""
    with open(src) as fh:
        header = fh.readline()
        rows = []
        for line in fh:
            if start_s is not None and float(line.split(",", 1)[0]) < start_s:
                continue
            rows.append(line)
            if len(rows) == n:
                break
    dst.write_text(header + "".join(rows))
    return dst


def symbols(elf: Path) -> dict[str, tuple[int, int]]:
    """Function name -> (address, size) from ``nm -S`` (thumb bit cleared)."""
    out = subprocess.run(["arm-none-eabi-nm", "-S", "--defined-only", str(elf)],
                         capture_output=True, text=True, check=True).stdout
    syms = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 4 and parts[2].lower() == "t":
            syms[parts[3]] = (int(parts[0], 16) & ~1, int(parts[1], 16))
    return syms


def callees(elf: Path, root: str) -> list[str]:
    """``root`` and every function it reaches by ``bl`` (transitively), from objdump."""
    dis = subprocess.run(["arm-none-eabi-objdump", "-d", "--no-show-raw-insn", str(elf)],
                         capture_output=True, text=True, check=True).stdout
    calls: dict[str, set[str]] = {}
    current = None
    for line in dis.splitlines():
        m = re.match(r"^[0-9a-f]+ <([^>]+)>:$", line)
        if m:
            current = m.group(1)
            calls.setdefault(current, set())
            continue
        m = re.search(r"\tbl\s+[0-9a-f]+ <([^>+]+)>", line)
        if m and current is not None:
            calls[current].add(m.group(1))
    seen, todo = [], [root]
    while todo:
        f = todo.pop()
        if f not in seen:
            seen.append(f)
            todo += sorted(calls.get(f, ()))
    return seen


def sizes(elf: Path) -> tuple[int, int]:
    out = subprocess.run(["arm-none-eabi-size", str(elf)], capture_output=True, text=True,
                         check=True).stdout
    text, data, bss = (int(v) for v in out.splitlines()[-1].split()[:3])
    return text + data, data + bss


def instructions_per_step(header: Path, model: dict, csv: Path, build: Path,
                          cflags: str) -> tuple[float, int, list[str]]:
    """(instructions per tcm_step call, calls seen, functions counted) under QEMU."""
    from thermal_comp.hil.build import build_firmware
    from thermal_comp.hil.feed import build_feed
    from thermal_comp.hil.qemu import QemuBox
    from thermal_comp.hil.runner import replay

    elf = build_firmware(header, build, "qemu_uartfeed", cflags)
    syms = symbols(elf)
    funcs = [f for f in callees(elf, MODEL_FUNCTION) if f in syms]
    trace = build / f"trace{cflags.replace(' ', '')}.log"
    ranges = ",".join(f"0x{syms[f][0]:x}+0x{syms[f][1]:x}" for f in funcs)
    args = ["-singlestep", "-d", "exec,nochain", "-dfilter", ranges, "-D", str(trace)]
    feed = build_feed(model, csv)
    # One sample in flight: single-stepped, the guest reads its USART far slower than a
    # 64-line chunk arrives, and the feed would overrun (measured: the box fell silent at
    # sample 8 of 30).
    capture = replay(feed, lambda _wdt: QemuBox(elf, extra_args=args), quiet=True,
                     timeout=120.0, window=1, chunk=1)
    errors = [s.error for s in capture.sessions if s.error]
    if errors:
        raise RuntimeError(f"QEMU replay under the trace failed: {errors[0]}")
    start = syms[MODEL_FUNCTION][0]
    spans = [(syms[f][0], syms[f][0] + syms[f][1]) for f in funcs]
    count = entries = 0
    last = -1
    with trace.open("rb") as fh:
        for line in fh:
            m = TRACE_PC.match(line)
            if not m:
                continue
            pc = int(m.group(1), 16)
            # An interrupt taken at a TB boundary logs that one-instruction TB, runs the
            # handler (outside the filter) and logs it again: the same pc twice in a row.
            # tcm_step has no branch-to-self, so a repeat is never a second execution.
            if pc == last or not any(a <= pc < b for a, b in spans):
                continue
            last = pc
            count += 1
            entries += pc == start
    if entries != feed.n_samples:
        raise RuntimeError(f"{trace}: {entries} entries into {MODEL_FUNCTION} for "
                           f"{feed.n_samples} samples fed")
    return count / entries, entries, funcs


def measure(label: str, model: dict, test_csv: str, start_s: float | None, tmp: Path) -> list[dict]:
    from thermal_comp import codegen
    from thermal_comp.hil.build import build_firmware

    work = tmp / re.sub(r"[^A-Za-z0-9]+", "_", label)  # the linker's -Map= takes no comma
    work.mkdir()
    header = work / "model.h"
    header.write_text(codegen.generate(model).text)
    n_terms = sum(len(a["terms"]) for a in model["axes"].values())
    detail = (f"{len(model['channels'])} channels, {len(model['aux'])} aux, "
              f"{len(model['axes'])} axes, {n_terms} terms")
    flash, ram = sizes(build_firmware(header, work, "stm32f405"))
    rows = [{"name": f"{label}: flash (text+data)", "value": flash, "unit": "bytes",
             "target": f"< {FLASH_BUDGET}", "goal": goal("<", FLASH_BUDGET), "detail": detail},
            {"name": f"{label}: RAM (data+bss, 1 KiB stack)", "value": ram, "unit": "bytes",
             "target": f"< {RAM_BUDGET}", "goal": goal("<", RAM_BUDGET), "detail": detail}]
    if shutil.which("qemu-system-arm") is None:
        _log("qemu-system-arm not installed: no instruction counts")
        return rows
    csv = head_csv(test_csv, work / "head.csv", N_SAMPLES, start_s)
    for cflags, opt in (("", "-Os, shipped"), ("-O3", "-O3")):
        per, calls, funcs = instructions_per_step(header, model, csv, work, cflags)
        rows.append({"name": f"{label}: instructions per model step ({opt})", "value": per,
                     "unit": "instr", "target": f"floor ~{DOT5_FLOOR_O3} for 5 terms at -O3",
                     "goal": INFO,
                     "detail": f"{detail}; {calls} steps traced in {', '.join(funcs)}; "
                     f"{per / max(1, n_terms):.1f} per term"})
    return rows


def run() -> list[dict]:
    from bench import bench_accuracy as acc

    rows: list[dict] = []
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        sim = acc.sim_jobs(tmp)[0]
        dev, fl = representative_cases()
        for label, job in (("sim machine 0", sim), ("sim_dev machine11 S1", dev),
                           ("FL 5 probes, cycle 4 out", fl)):
            _log(f"{label}: training the default model")
            model = train_default(job)
            test = job.test[0]
            rows += measure(label, model, test.path, test.start_s, tmp)
    return rows


if __name__ == "__main__":
    for row in run():
        print(f"{row['name']:<58} {row['value']:>10.1f} {row['unit']:<6} {row.get('target', '')}"
              f"  {row.get('detail', '')}")
