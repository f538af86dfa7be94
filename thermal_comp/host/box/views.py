"""What `host monitor` shows of its state: the live lines (``render``, the in-service
estimate), a plain line for a pipe, a JSON record for --json."""

from __future__ import annotations

from thermal_comp.contract.tilt import unit_of, unit_text
from thermal_comp.host.box.screen import GREY, RED, RESET
from thermal_comp.host.box.state import (
    STALE_PERIODS,
    MonitorState,
    flags_text,
    hash_line,
    reference_line,
)

# ---- in service (issue 42): the estimator per axis, from the STATUS line -----------------
REFUSALS_WARN = 2  # readings the gate refused in a row that the view calls out


def service_lines(state: MonitorState, colour: bool = False) -> list[str]:
    """Per axis the box's in-service estimate (the bias MEAS taught it) and the last
    reading's residual (innovation); repeated refusals in red: the model misses by more than
    the gate lets through (or the artifact is dirty), and the estimate stays where it was."""
    svc = getattr(state.status_report, "service", None)
    if not svc:
        return []
    red, reset = (RED, RESET) if colour else ("", "")
    out = []
    for name, a in zip(state.axis_names(len(svc)), svc, strict=True):
        if a is None:
            out.append(f"  estimate   {name:>10}: off (no service block: MEAS refused)")
            continue
        unit = unit_text(name)
        res = "-" if a.innovation_nm is None else f"{a.innovation_nm / 1000.0:+.3f} {unit}"
        line = f"  estimate {name:>5}: {a.bias_nm / 1000.0:+8.3f} {unit}, last residual {res}"
        # short marks first (the alarm before the history), their explanations after: the
        # screen clips a line at 79 columns, and the marks still fit there
        marks, why = [], []
        if a.refusals >= REFUSALS_WARN:
            marks.append(f"{a.refusals} REFUSED")
            why.append(f"({a.refusals} readings refused in a row, beyond the gate: check the "
                       "artifact, or ZERO)")
        elif a.refusals:
            marks.append(f"{a.refusals} refused")
        if a.reopens:
            marks.append(f"REOPENED {a.reopens}x")
            why.append("(re-opened: refusals in a row that agreed: the model missed beyond "
                       "the gate, or a chip stuck on the artifact)")
        line = ", ".join([line, *marks]) + "".join(f" {w}" for w in why)
        out.append(f"{red}{line}{reset}" if a.refusals >= REFUSALS_WARN else line)
    return out


def render(state: MonitorState, now: float, colour: bool = False) -> list[str]:
    """The live state as lines (the terminal view shows these above the fault history)."""
    grey, red, reset = (GREY, RED, RESET) if colour else ("", "", "")
    if state.connected:
        link = "connected"
    else:
        gone = ("" if state.disconnected_at is None
                else f" for {now - state.disconnected_at:.1f} s")
        link = f"{red}DISCONNECTED{gone}, retrying{reset}"
    lines = [f"host monitor on {state.port}: {link}", hash_line(state)]
    silence, limit = state.silence_s(now), state.stale_after_s()
    if silence is not None and limit is not None and silence > limit:
        lines.append(f"{red}STALE: no sample for {silence:.1f} s (expected every "
                     f"{limit / STALE_PERIODS:g} s): the values below are old{reset}")
    s = state.sample
    if s is None:
        lines.append("no sample yet")
    else:
        age = "" if silence is None else f", {silence:.1f} s ago"
        lines.append(f"sample #{s.seq}{age}   status {s.status:04X}: {flags_text(state, ', ')}")
        lines.append(f"  offset to apply = −correction; {reference_line(state)}")
        held = set(state.held_axes() or [])
        for name, nm in zip(state.axis_names(len(s.corrections_nm)), s.corrections_nm,
                            strict=True):
            mark = "  (HOLD: last good value)" if name in held else ""
            lines.append(f"  correction {name:>10}: {nm / 1000.0:+10.3f} "
                         f"{unit_text(name)}{mark}")
        lines += service_lines(state, colour)
        if state.hash_ok is True:
            for name in state.axis_names(len(s.corrections_nm)):
                if state.promises.get(name):
                    lines.append(f"  promised   {name:>10}: {state.promises[name]}")
        invalid = state.invalid_channels()
        temps = []
        for name, code in zip(state.channel_names(len(s.temp_codes)), s.temp_codes,
                              strict=True):
            if name in invalid:
                temps.append(f"{grey}{name} {invalid[name]:>9}{reset}")
            else:
                temps.append(f"{name} {code / 128.0:7.2f} °C")
        for i in range(0, len(temps), 4):
            lines.append("  " + "   ".join(temps[i:i + 4]))
    lines.append(f"samples {state.samples}   bad lines {state.bad_lines}   "
                 f"seq gaps {state.seq_gaps}   reconnects {state.reconnects}"
                 + (f"   withheld {state.withheld}" if state.withheld else ""))
    if state.last_bad:
        lines.append(f"  last bad line: {state.last_bad}")
    return lines


def plain_sample_line(state: MonitorState) -> str:
    """One line per sample when the output is not a terminal (logs, pipes, scripts)."""
    s = state.sample
    assert s is not None
    corr = " ".join(f"{n}={nm / 1000.0:+.3f}{unit_of(n)}" for n, nm in
                    zip(state.axis_names(len(s.corrections_nm)), s.corrections_nm, strict=True))
    invalid = state.invalid_channels()
    temps = " ".join(f"{n}=FAULT({invalid[n]})" if n in invalid else
                     f"{n}={c / 128.0:.2f}C" for n, c in
                     zip(state.channel_names(len(s.temp_codes)), s.temp_codes, strict=True))
    flags = flags_text(state, ",")
    return (f"seq={s.seq} status={s.status:04X}[{flags}] {corr} {temps} "
            f"bad={state.bad_lines}".replace("  ", " "))


def json_sample(state: MonitorState, received: float) -> dict:
    """One sample as the ``--json`` object: corrections per axis (µm; µrad for a tilt axis,
    named in ``units``), temperatures (°C, null for a faulted channel) per sensor, flags,
    faulted channels and held axes."""
    s = state.sample
    assert s is not None
    faulted = state.faulted_channels()
    invalid = state.invalid_channels()
    names = state.channel_names(len(s.temp_codes))
    return {
        "type": "sample", "seq": s.seq, "status": f"{s.status:04X}", "flags": state.flags,
        "corrections_um": {n: nm / 1000.0 for n, nm in
                           zip(state.axis_names(len(s.corrections_nm)), s.corrections_nm,
                               strict=True)},
        "units": {n: unit_of(n) for n in state.axis_names(len(s.corrections_nm))},
        "temperatures_c": {n: (None if n in invalid else c / 128.0)
                           for n, c in zip(names, s.temp_codes, strict=True)},
        "faulted_channels": faulted, "held_axes": state.held_axes(),
        "beyond_training": state.beyond_training(),
        "referenced": "REFERENCED" in state.flags, "zero_seq": state.zero_seq(),
        "model_hash_ok": state.hash_ok, "host_unix_s": round(received, 3),
    }
