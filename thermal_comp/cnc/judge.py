"""A `make cnc` session judged (docs/linuxcnc.md): LinuxCNC's offsets against the box's own
lines per sample, each held fault, ZERO, and each controller event against the clean run."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from thermal_comp.cnc.scenario import AXES, CONFIG_DIR, HOLD_BITS, MOVED_NM, SIGN, Scenario


@dataclass
class Result:
    summary: dict
    raw: dict
    problems: list[str] = field(default_factory=list)


@dataclass
class _Records:
    """The session's sample records, by sample and by phase, with the box's correction and
    LinuxCNC's offset of each in nm."""

    records: list[dict]
    base: dict  # each axis's joint position before the session (mm)
    nm_per_count: float
    letters: list[str] = field(default_factory=lambda: [letter for letter, _ in AXES])
    idx: dict[int, dict] = field(init=False)
    by_phase: dict[str, list[dict]] = field(init=False)

    def __post_init__(self) -> None:
        self.idx = {r["sample"]: r for r in self.records}
        self.by_phase = {}
        for r in self.records:
            self.by_phase.setdefault(r["phase"], []).append(r)

    def want_nm(self, rec: dict, i: int) -> float:
        return SIGN * rec["box"]["corr_nm"][i] if rec["box"]["corr_nm"] else float("nan")

    def offset_diff_nm(self, rec: dict) -> float:
        """|LinuxCNC's external offset - the box's correction|, the worst axis."""
        return max(abs(rec["eoffset_mm"][a] * 1e6 - self.want_nm(rec, i))
                   for i, a in enumerate(self.letters))

    def joint_diff_nm(self, rec: dict) -> float:
        """|the joint's commanded move since the start - the box's correction|, worst axis."""
        return max(abs((rec["pos_cmd_mm"][a] - self.base[a]) * 1e6 - self.want_nm(rec, i))
                   for i, a in enumerate(self.letters))

    def moved_nm(self, rs: list[dict], ref: dict) -> float:
        return max((abs(r["eoffset_mm"][a] - ref["eoffset_mm"][a]) * 1e6
                    for r in rs for a in self.letters), default=0.0)


def _tracking(rec: _Records, problems: list[str],
              cuts: tuple[int, ...] = ()) -> tuple[int, float, float]:
    """On every healthy sample, the offset and the joint follow the box within a count:
    (samples tracked, worst offset difference, worst joint difference) in nm.

    After a power cut the component carries the offsets it held as a base and adds the box's
    change since the operator's ZERO: from then on the offset is base - correction, the base
    taken at the first healthy sample after the cut (the power cut's row judges the base
    itself against the clean run)."""
    max_off = max_joint = 0.0
    tracked = 0
    base = {a: 0.0 for a in rec.letters}
    segment = 0
    for r in rec.records:
        while segment < len(cuts) and r["sample"] >= cuts[segment]:
            segment, base = segment + 1, {}
        healthy = (not r["box"]["status"] & HOLD_BITS and not r["holding"]
                   and not r["walking"] and not r["box"]["corrupted"]
                   and r["box"].get("delivered", True)
                   and r["phase"] not in ("machine_off", "disabled", "garbage"))
        if not healthy:
            continue
        if not base:
            base = {a: r["eoffset_mm"][a] * 1e6 - rec.want_nm(r, i)
                    for i, a in enumerate(rec.letters)}
        tracked += 1
        max_off = max(max_off, max(abs(r["eoffset_mm"][a] * 1e6 - base[a] - rec.want_nm(r, i))
                                   for i, a in enumerate(rec.letters)))
        max_joint = max(max_joint, max(
            abs((r["pos_cmd_mm"][a] - rec.base[a]) * 1e6 - base[a] - rec.want_nm(r, i))
            for i, a in enumerate(rec.letters)))
    if tracked == 0:
        problems.append("no sample was tracked (every one held or walking)")
    if max_off > rec.nm_per_count:
        problems.append(f"LinuxCNC's external offset differs from the box's correction by "
                        f"{max_off:.3f} nm (> 1 count = {rec.nm_per_count:g} nm)")
    if max_joint > rec.nm_per_count:
        problems.append(f"the joints' commanded positions moved by the correction ± "
                        f"{max_joint:.3f} nm (> 1 count)")
    return tracked, max_off, max_joint


def _open_thermocouple(rec: _Records, step_nm: float, problems: list[str]) -> list[dict]:
    """Held on every sample of the fault, then walked back no faster than the step limit."""
    opened = rec.by_phase.get("open", [])
    if not opened:
        return []
    letters = rec.letters
    before = rec.idx.get(opened[0]["sample"] - 1)
    boxheld = sum(1 for r in opened if r["box"]["status"] & (1 << 1))
    moved = rec.moved_nm(opened, before) if before else float("nan")
    ok = before is not None and moved <= MOVED_NM and all(r["holding"] for r in opened) \
        and boxheld == len(opened)
    after = [rec.idx[k] for k in range(opened[-1]["sample"], opened[-1]["sample"] + 20)
             if k in rec.idx]
    steps = [abs(b["eoffset_mm"][a] - p["eoffset_mm"][a]) * 1e6
             for p, b in zip(after[:-1], after[1:], strict=True) for a in letters]
    walk_ok = max(steps, default=0.0) <= step_nm + rec.nm_per_count
    if not ok:
        problems.append(f"open thermocouple: offsets moved {moved:g} nm or were not held "
                        f"on every sample ({boxheld}/{len(opened)} HOLD from the box)")
    if not walk_ok:
        problems.append(f"after the open thermocouple an offset stepped "
                        f"{max(steps):g} nm in one sample (limit {step_nm:g})")
    return [{"fault": "open thermocouple", "samples": len(opened),
             "box_status": "OPEN|HOLD" if boxheld else "-", "held": ok,
             "moved_nm": moved, "walk_back_ok": walk_ok}]


def _stale_pauses(raw: dict, rec: _Records, problems: list[str]) -> list[dict]:
    """A silent box: the driver flags stale and holds, and nothing moves."""
    holds = []
    for p in [r for r in raw.get("records", []) if r.get("phase") == "stale_pause"]:
        b, d = p["before"], p["during"]
        moved = max(abs(d["eoffset_mm"][a] - b["eoffset_mm"][a]) * 1e6 for a in rec.letters)
        ok = bool(d["stale"]) and bool(d["holding"]) and moved <= MOVED_NM and not b["stale"]
        holds.append({"fault": "stale stream", "samples": 0, "box_status": "(silent)",
                      "held": ok, "moved_nm": moved, "age_s": d["age-s"]})
        if not ok:
            problems.append(f"stale stream: stale={d['stale']} holding={d['holding']} "
                            f"moved {moved:g} nm (age {d['age-s']:.3f} s)")
    return holds


def _corrupted_lines(rec: _Records, problems: list[str]) -> list[dict]:
    """A line with a bad CRC is refused (counted) and moves nothing."""
    holds = []
    for r in rec.by_phase.get("bad_line", []):
        prev = rec.idx.get(r["sample"] - 1)
        moved = rec.moved_nm([r], prev) if prev else float("nan")
        refused = prev is not None and r["bad-lines"] == prev["bad-lines"] + 1
        ok = r["box"]["corrupted"] and refused and moved <= MOVED_NM
        holds.append({"fault": "corrupted line (CRC)", "samples": 1, "box_status": "-",
                      "held": ok, "moved_nm": moved})
        if not ok:
            problems.append(f"corrupted line at sample {r['sample']}: refused={refused}, "
                            f"offsets moved {moved:g} nm")
    return holds


def _machine_off_on(rec: _Records, problems: list[str]) -> tuple[list[dict], dict]:
    """After machine off/on the offset and the joint are back on the box's correction."""
    holds: list[dict] = []
    resync: dict = {}
    for r in rec.by_phase.get("machine_on", []):
        d_off, d_joint = rec.offset_diff_nm(r), rec.joint_diff_nm(r)
        resync = {"sample": r["sample"], "offset_diff_nm": d_off, "joint_diff_nm": d_joint,
                  "ok": d_off <= rec.nm_per_count and d_joint <= rec.nm_per_count}
        holds.append({"fault": "machine off/on",
                      "samples": len(rec.by_phase.get("machine_off", [])), "box_status": "-",
                      "held": resync["ok"], "moved_nm": d_off})
        if not resync["ok"]:
            problems.append(f"after machine off/on the offset is {d_off:g} nm and the joint "
                            f"{d_joint:g} nm away from the box's correction")
    return holds, resync


def _enable_off_on(rec: _Records, problems: list[str]) -> list[dict]:
    """Disabled, the offset is 0; enabled again, it is the box's correction."""
    disabled = rec.by_phase.get("disabled", [])
    if not disabled:
        return []
    off = max(abs(r["eoffset_mm"][a]) * 1e6 for r in disabled for a in rec.letters)
    d_back = max((rec.offset_diff_nm(r) for r in rec.by_phase.get("enabled", [])),
                 default=float("inf"))
    ok = off <= rec.nm_per_count and d_back <= rec.nm_per_count
    if not ok:
        problems.append(f"enable off/on: offset {off:g} nm while disabled (want 0), "
                        f"{d_back:g} nm from the box's value after enable")
    return [{"fault": "enable off/on", "samples": len(disabled),
             "box_status": "-", "held": ok, "moved_nm": d_back}]


def _zero(raw: dict, rec: _Records, problems: list[str]) -> dict:
    """After ZERO the box sends 0 and LinuxCNC's offset and joint are back at their start."""
    zero: dict = {"done": False, "ok": False}
    sent = [r for r in raw.get("records", []) if r.get("phase") == "zero_sent"]
    for r in rec.by_phase.get("zero", []):
        box_zero = all(c == 0 for c in r["box"]["corr_nm"])
        off = max(abs(r["eoffset_mm"][a]) * 1e6 for a in rec.letters)
        joint = max(abs(r["pos_cmd_mm"][a] - rec.base[a]) * 1e6 for a in rec.letters)
        zero = {"done": True, "sample": r["sample"], "reply": sent[0]["reply"] if sent else "",
                "box_zero": box_zero, "offset_nm": off, "joint_nm": joint,
                "referenced": bool(r["box"]["status"] & (1 << 11)),
                "ok": box_zero and off <= rec.nm_per_count and joint <= rec.nm_per_count}
        if not zero["ok"]:
            problems.append(f"ZERO: box output {r['box']['corr_nm']}, LinuxCNC offset "
                            f"{off:g} nm, joint {joint:g} nm from its start")
    return zero


# --- the rule: no single event worse than the clean run by more than one step limit --------
def clean_reference(setup, scenario: Scenario) -> dict:
    """The offsets a clean session would command, computed without the component or LinuxCNC.

    The clean box's lines come from the host's twin (hil.expect: bit-exact with the firmware,
    as the HIL checks) for the same feed with only the non-controller events (the open
    thermocouple, the job's ZERO and the ZERO at ``zero_at``); the component's documented
    rules (docs/linuxcnc.md) turn them into offsets: hold every axis on a hold bit, else move
    towards sign x correction by at most min(step limit, slew) per line, within
    ``max_abs_um``, and take the first line after an acknowledged ZERO at once."""
    import numpy as np

    from thermal_comp.cnc import thermalcomp
    from thermal_comp.contract.fixed_point import CODE_MAX, CODE_MIN
    from thermal_comp.hil.expect import expect_session, sr_timeline

    feed, model = setup.feed, setup.spec
    n = feed.n_samples
    codes = np.clip(np.asarray(feed.codes, dtype=np.int64), CODE_MIN, CODE_MAX)
    faults = []
    if scenario.open_at is not None and scenario.open_at < n:
        faults = [(scenario.open_at, scenario.open_channel, 1),
                  (min(scenario.open_stop, n), scenario.open_channel, 0)]
    sr = sr_timeline(n, codes.shape[1], [f for f in faults if f[0] < n])
    zeros = ([0] if scenario.zero_at_start else []) + (
        [scenario.zero_at] if scenario.zero_at is not None and scenario.zero_at < n else [])
    exp = expect_session(setup.twin, codes, feed.aux, sr, setup.output, zero_before=zeros,
                         zero_at_powerup=setup.build.zero_at_powerup)
    cfg = thermalcomp.load_config(CONFIG_DIR / "thermalcomp.conf")
    names = model.axis_names
    steps = {a.letter: float(thermalcomp.axis_step_nm(CONFIG_DIR, f"axis.{a.letter}",
                                                        a.box_axis, model, None, True))
             for a in cfg.axes}
    offset = _component_offsets(cfg, names, exp, zeros, steps, model.sample_period_s)
    return {"corr_nm": [[int(v) for v in row] for row in exp.out_nm],
            "status": [int(v) for v in exp.status], "offset_nm": offset, "step_nm": steps,
            "nm_per_count": {a.letter: a.nm_per_count for a in cfg.axes},
            "box_axes": {a.letter: names.index(a.box_axis) for a in cfg.axes}}


def _component_offsets(cfg, names: list[str], exp, zeros: list[int], steps: dict[str, float],
                       period_s: float) -> dict[str, list[float]]:
    """The component's documented rules on the twin's lines: hold on a hold bit, else move
    towards sign x correction by at most min(step limit, slew) per line, within max_abs_um;
    the first line after a ZERO is taken at once."""
    from thermal_comp.cnc import thermalcomp

    slew_nm = cfg.slew_nm_per_s * round(period_s * 1000.0) / 1000.0
    max_abs_nm = cfg.max_abs_um * 1000.0
    offset: dict[str, list[float]] = {a.letter: [] for a in cfg.axes}
    want = {a.letter: 0 for a in cfg.axes}
    datum = False
    for k in range(len(exp.status)):
        datum = datum or k in zeros
        if not exp.status[k] & thermalcomp.HOLD_BITS:  # on a hold bit every axis keeps its
            for a in cfg.axes:                         # offset (a datum waits for the next line)
                bound = math.floor(max_abs_nm / a.nm_per_count + 1e-9)
                corr = int(exp.out_nm[k, names.index(a.box_axis)])
                target = max(-bound, min(bound, round(a.sign * corr / a.nm_per_count)))
                if datum:
                    want[a.letter] = target
                else:
                    step = max(1, math.floor(min(steps[a.letter], slew_nm) / a.nm_per_count
                                             + 1e-9))
                    w = want[a.letter]
                    want[a.letter] = max(-bound, min(bound, w + max(-step, min(step,
                                                                                target - w))))
            datum = False
        for a in cfg.axes:
            offset[a.letter].append(want[a.letter] * a.nm_per_count)
    return offset


FLAG_SAMPLES = 10  # the flags reported for an event: those seen in its first samples
_FLAG_PINS = ("holding", "fault", "stale", "awaiting-zero", "walking", "model-mismatch")
_COUNTERS = ("bad-lines", "lost-lines", "restarts", "zero-acks")


def _flags(window: list[dict], before: dict | None, clean_status: list[int]) -> list[str]:
    """The component's flags seen over a window, its counters' increments, and the box's
    status bits that the clean run does not have there."""
    flags = [pin for pin in _FLAG_PINS if any(r.get(pin) for r in window)]
    if any(not r.get("connected", True) for r in window):
        flags.append("disconnected")
    for c in _COUNTERS:
        most = max((r[c] for r in window if c in r), default=None)
        if most is not None and before is not None and most > before[c]:
            flags.append(f"{c} +{most - before[c]}")
    extra = 0
    for r in window:
        if "box" in r and r["sample"] < len(clean_status):
            extra |= r["box"]["status"] & ~clean_status[r["sample"]]
    from thermal_comp.contract.protocol import status_names

    flags += [f"box {name}" for name in status_names(extra)]
    return flags


def _judge_events(raw: dict, rec: _Records, clean: dict, events: list[tuple[str, int]],
                  problems: list[str]) -> list[dict]:
    """Per controller event: over its samples (from the event to the next one, or the end),
    per axis the largest |LinuxCNC offset - the clean run's offset|, against one step limit
    (+ 1 count). Samples with the machine off or compensation disabled are not compared."""
    n = len(clean["status"])
    extras = [r for r in raw.get("records", []) if r.get("phase") in ("forged", "stale_pause")]
    rows = []
    for i, (name, at) in enumerate(events):
        end = events[i + 1][1] if i + 1 < len(events) else n
        window = [r for r in rec.records if at <= r["sample"] < end
                  and r["phase"] not in ("machine_off", "disabled")]
        # (snapshot, the sample whose clean offset the tool should have then)
        compared = [(r, r["sample"]) for r in window]
        for x in extras:
            if at <= x["sample"] < end:
                if x["phase"] == "forged":
                    compared.append((x, x["sample"]))
                elif x["sample"] > 0:
                    compared.append((x["during"], x["sample"] - 1))
        inc, bound, detail = {}, {}, []
        ok = bool(window)
        for a in rec.letters:
            worst = max((abs(r["eoffset_mm"][a] * 1e6 - clean["offset_nm"][a][k])
                         for r, k in compared), default=float("nan"))
            inc[a] = worst / 1000.0
            bound[a] = clean["step_nm"][a] / 1000.0
            if not worst <= clean["step_nm"][a] + clean["nm_per_count"][a]:
                ok = False
        before = rec.idx.get(at - 1)
        # the flags of the event itself: its first FLAG_SAMPLES samples
        near = [r for r in window if r["sample"] < at + FLAG_SAMPLES]
        flags = _flags(near + [x for x, k in compared if "box" not in x
                               and k < at + FLAG_SAMPLES], before, clean["status"])
        row = {"scenario": name, "where": "linuxcnc", "at": at, "until": end,
               "increase_um": inc, "bound_um": bound, "flags": flags}
        ok &= _event_checks(name, at, raw, rec, window, before, detail)
        row["ok"] = ok
        row["detail"] = "; ".join(detail) or f"samples {at}-{end - 1}"
        if not ok:
            problems.append(f"{name} at sample {at}: increase "
                            + ", ".join(f"{a} {inc[a]:.3f}" for a in rec.letters)
                            + " um (bound " + ", ".join(f"{bound[a]:.3f}" for a in rec.letters)
                            + f" um + 1 count); {row['detail']}")
        rows.append(row)
    return rows


def _moved_nm(a: dict, b: dict, letter: str) -> float:
    return abs(a["eoffset_mm"][letter] - b["eoffset_mm"][letter]) * 1e6


def _event_checks(name: str, at: int, raw: dict, rec: _Records, window: list[dict],
                  before: dict | None, detail: list[str]) -> bool:
    """What each event must also show besides the bound (so the bound is not met by luck)."""
    ok = True
    if name == "forged line":
        forged = [r for r in raw.get("records", []) if r.get("phase") == "forged"
                  and r["sample"] == at]
        here = rec.idx.get(at)
        if not forged or here is None:
            detail.append("the forged line was not injected")
            return False
        moved = {a: _moved_nm(forged[0], here, a) / 1000.0 for a in rec.letters}
        taken = all(m > 0.5 * rec.nm_per_count / 1000.0 for m in moved.values())
        detail.append("the forged line (+60 um) moved the offsets "
                      + ", ".join(f"{a} {moved[a]:.3f}" for a in rec.letters) + " um"
                      + ("" if taken else ": NOT taken"))
        ok &= taken
    elif name.startswith("power cut"):
        cut = [r for r in window if r["sample"] <= at + 1]
        zero = [r for r in raw.get("records", []) if r.get("phase") == "zero_after_cut"
                and "box" not in r and at < r["sample"]]
        held = before is not None and all(_moved_nm(r, before, a) <= MOVED_NM
                                          for r in cut for a in rec.letters)
        no_ref = any(r["box"]["status"] & (1 << 13) for r in cut)
        replied = bool(zero) and zero[0].get("reply", "").startswith("$OK,ZERO")
        # or the component gave the box its kept state back (LOAD, RESUME): its datum goes on
        # (the old sequence continues after the cut) and the operator has nothing to touch off
        resumed = bool(zero) and "skipped" in zero[0] and any(
            r["box"]["seq"] > (before or {}).get("box", {}).get("seq", 1 << 32)
            and r["box"]["status"] & (1 << 11) for r in window)
        what = (zero[0].get("reply") or zero[0].get("skipped")) if zero else "not sent"
        detail.append(f"box NO_REF {'yes' if no_ref else 'NO'}, offsets held "
                      f"{'yes' if held else 'NO'}, ZERO at {zero[0]['sample'] if zero else '-'}"
                      f" ({what}; awaiting-zero before "
                      f"it: {'yes' if zero and zero[0]['awaiting_zero_before'] else 'no'})")
        ok &= held and no_ref and (replied or resumed)
    elif name == "watchdog restart":
        r = rec.idx.get(at)
        resumed = (r is not None and before is not None
                   and r["box"]["seq"] == before["box"]["seq"] + 1
                   and bool(r["box"]["status"] & (1 << 8)))
        detail.append(f"seq {before['box']['seq'] if before else '?'} -> "
                      f"{r['box']['seq'] if r else '?'}, WDT_RESET "
                      f"{'yes' if r and r['box']['status'] & (1 << 8) else 'NO'}")
        ok &= resumed
    elif name == "reconnect":
        down = [r for r in window if r["phase"] == "link_down"]
        lost = sum(1 for r in down if not r["box"].get("delivered", True))
        dropped = any(not r["connected"] for r in down)
        detail.append(f"link down for {lost} box line(s), component saw it: "
                      f"{'yes' if dropped else 'NO'}")
        ok &= dropped and lost == len(down) > 0
    elif name == "garbage on the wire":
        r = rec.idx.get(at)
        refused = r is not None and before is not None and r["bad-lines"] > before["bad-lines"]
        detail.append(f"bad lines +{r['bad-lines'] - before['bad-lines'] if refused else 0}")
        ok &= refused
    return ok


def _box_against_twin(rec: _Records, clean: dict, cuts: tuple[int, ...]) -> dict:
    """The box's lines as the tap decoded them against the twin's clean lines, on every
    sample before the first power cut (a watchdog restart resumes bit for bit)."""
    stop = min(cuts, default=len(clean["status"]))
    compared = mismatches = 0
    for r in rec.records:
        if r["sample"] >= stop:
            continue
        compared += 1
        want = clean["corr_nm"][r["sample"]]
        mask = ~(1 << 8)  # WDT_RESET: set after the watchdog restart only
        if r["box"]["corr_nm"] != want or (r["box"]["status"] & mask) != (
                clean["status"][r["sample"]] & mask):
            mismatches += 1
    return {"compared": compared, "mismatches": mismatches}


def fault_rows(summary: dict) -> list[dict]:
    """One row per controller event of a session's summary (``run_session``), for the fault
    campaign: {scenario, where, increase_um, bound_um, flags, ok, detail}."""
    keys = ("scenario", "where", "increase_um", "bound_um", "flags", "ok", "detail")
    return [{k: row[k] for k in keys} for row in summary.get("events", [])]


def judge(raw: dict, nm_per_count: float = 1.0, step_nm: float = 60_000.0,
          clean: dict | None = None, events: list[tuple[str, int]] | None = None) -> Result:
    """Compare LinuxCNC's offsets with the box's lines, and (given the clean run's offsets,
    ``clean_reference``) each controller event with the clean run; the summary and the
    problems found."""
    problems: list[str] = []
    rec = _Records([r for r in raw.get("records", []) if "box" in r],
                   raw.get("base_pos_mm", {}), nm_per_count)
    cuts = tuple(at for name, at in events or [] if name.startswith("power cut"))
    tracked, max_off, max_joint = _tracking(rec, problems, cuts)
    holds = _open_thermocouple(rec, step_nm, problems)
    holds += _stale_pauses(raw, rec, problems)
    holds += _corrupted_lines(rec, problems)
    resync_holds, resync = _machine_off_on(rec, problems)
    holds += resync_holds
    holds += _enable_off_on(rec, problems)
    zero = _zero(raw, rec, problems)
    rows = _judge_events(raw, rec, clean, events or [], problems) if clean else []
    twin = _box_against_twin(rec, clean, cuts) if clean else {}
    if twin.get("mismatches"):
        problems.append(f"the box's own lines differ from the twin's clean lines on "
                        f"{twin['mismatches']} of {twin['compared']} samples before the first "
                        "power cut: the clean reference is not the box's")
    if not raw.get("ok"):
        problems.insert(0, f"the LinuxCNC session did not complete: {raw.get('error')}")
    records = rec.records
    summary = {"samples": len(records), "tracked_samples": tracked,
               "max_abs_diff_nm": max_off, "max_abs_diff_counts": max_off / nm_per_count,
               "max_abs_joint_diff_nm": max_joint, "holds": holds, "resync": resync,
               "zero": zero, "zero_ok": bool(zero.get("ok")), "events": rows,
               "box_vs_twin": twin,
               "bad_lines": records[-1]["bad-lines"] if records else 0,
               "lost_lines": records[-1]["lost-lines"] if records else 0,
               "ok": not problems, "problems": problems}
    return Result(summary, raw, problems)
