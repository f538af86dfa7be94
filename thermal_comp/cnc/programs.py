"""The test programs a `make cnc` session runs (host testplan --dialect linuxcnc), judged
against the spindle and trigger pins the driver recorded."""

from __future__ import annotations

from thermal_comp.host.sim import ThermalTestPlan, build_program


def short_testplan() -> ThermalTestPlan:
    """A time-compressed thermal test for LinuxCNC: the step protocol in 2 s steps (2000 to
    8000 rpm), 8 s running and 4 s cooling, a measurement every 2 s with a 0.5 s stop, the
    logger on digital output 0 (``M64 P0``): 7 measurements, 12.5 s."""
    prog = build_program("step", 8000.0, hours=8 / 3600, cool_hours=4 / 3600,
                         step_minutes=2 / 60)
    return ThermalTestPlan(prog, 2.0, 0.5, "M64 P0", "linuxcnc")


def short_mcode_testplan() -> ThermalTestPlan:
    """The user M-code trigger (``M100 P<k>``, cnc/config/mcodes/M100): 4 s at 6000 rpm, 2 s
    cooling, a measurement every 2 s with a 0.5 s stop: 4 measurements, 6.5 s."""
    prog = build_program("constant", 8000.0, hours=4 / 3600, cool_hours=2 / 3600)
    return ThermalTestPlan(prog, 2.0, 0.5, "M100", "linuxcnc")


def default_testplans() -> tuple[ThermalTestPlan, ...]:
    return (short_testplan(), short_mcode_testplan())


def _state_at(events: list[dict], pin: str, t: float) -> object:
    value = None
    for e in events:
        if e["t"] > t:
            break
        if e["pin"] == pin:
            value = e["value"]
    return value


def judge_program(plan: ThermalTestPlan, rec: dict | None, tol_s: float = 0.25) -> dict:
    """The program as LinuxCNC ran it (pin changes against wall time) against the plan's
    schedule: a trigger pulse at every measurement time, spindle stopped and oriented then,
    and the protocol's speed in every running window. Time 0 is the first trigger."""
    problems: list[str] = []
    out: dict = {"trigger": plan.trigger, "measurements_expected": plan.n_intervals + 1,
                 "problems": problems}
    if not rec:
        problems.append("the test program was not run")
        return out
    if rec.get("error"):
        problems.append(f"LinuxCNC reported an error running {plan.trigger} test program: "
                        f"{rec['error']}")
    ev = rec["events"]
    rises = [e["t"] for i, e in enumerate(ev) if e["pin"] == "trigger" and e["value"]
             and _state_at(ev[:i], "trigger", e["t"]) in (False, None)]
    falls = [e["t"] for e in ev if e["pin"] == "trigger" and e["value"] is False]
    out["measurements_found"] = len(rises)
    if len(rises) != plan.n_intervals + 1:
        problems.append(f"{len(rises)} trigger pulses, the plan has {plan.n_intervals + 1}")
        return out
    numbers = [e.get("number") for e in ev if e["pin"] == "trigger" and e["value"]]
    if plan.digital_output is None and numbers != [f"{k}" for k in range(len(rises))] and \
            [float(n) for n in numbers] != [float(k) for k in range(len(rises))]:
        problems.append(f"the M-code got measurement numbers {numbers}")
    t0 = rises[0]
    expected = plan.measurement_times_s()
    errors = [abs((r - t0) - e) for r, e in zip(rises, expected, strict=True)]
    widths = [f - r for r, f in zip(rises, [f for f in falls if f > t0], strict=False)]
    out["max_trigger_error_s"] = max(errors)
    out["pulse_s"] = [round(w, 3) for w in widths]
    if max(errors) > tol_s:
        problems.append(f"a trigger came {max(errors):.3f} s off its scheduled time "
                        f"(tolerance {tol_s} s)")
    if plan.digital_output is not None and any(abs(w - plan.measure_s) > tol_s
                                               for w in widths):
        problems.append(f"trigger pulses of {widths} s, the stop is {plan.measure_s} s")
    bad_stop = [k for k, r in enumerate(rises)
                if _state_at(ev, "on", r + 0.01) or not _state_at(ev, "oriented", r + 0.01)]
    out["stopped_and_oriented"] = len(rises) - len(bad_stop)
    if bad_stop:
        problems.append(f"measurements {bad_stop}: spindle not stopped and oriented")
    p, d = plan.measure_every_s, plan.measure_s
    checked, wrong = 0, []
    for k in range(plan.n_intervals):
        mid = k * p + d + (p - d) / 2  # the middle of interval k's running window
        want = float(plan.program.rpm_at(k * p + (p - d) / 2))
        on = bool(_state_at(ev, "on", t0 + mid))
        got = float(_state_at(ev, "speed", t0 + mid) or 0.0) if on else 0.0
        checked += 1
        if abs(got - want) > 0.5:
            wrong.append((k, want, got))
    out["speeds_checked"], out["speeds_wrong"] = checked, wrong
    out["speeds"] = sorted({float(plan.program.rpm_at(k * p)) for k in range(plan.n_intervals)})
    if wrong:
        problems.append(f"spindle speed off the schedule in intervals (k, want, got) {wrong}")
    return out
