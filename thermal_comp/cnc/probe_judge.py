"""`make probe` judged (issue 42, docs/linuxcnc.md "Probing in service"): each reading
against the truth and the estimator's twin, the chip's refusal, updated against static."""

from __future__ import annotations

import math

from thermal_comp.cnc.scenario import AXES, MOVED_NM, PROBE_AXIS, SIGN, Scenario, drift_nm
from thermal_comp.contract import protocol

# The probe's resolution: the slow touch's travel in one servo period ([PROBE]SLOW_FEED 3 mm/min
# x [EMCMOT]SERVO_PERIOD 1 ms = 50 nm), plus one count of the offset (1 nm).
PROBE_RESOLUTION_NM = 3.0 / 60.0 * 1e-3 * 1e6 + 1.0


def _probe_records(raw: dict) -> tuple[dict | None, list[dict]]:
    recs = raw.get("records", [])
    ref = next((r for r in recs if r.get("phase") == "probe_ref"), None)
    return ref, [r for r in recs if r.get("phase") == "probe"]


def judge_probes(raw: dict, setup, scenario: Scenario, static: dict) -> dict:
    """Each probe against the truth and the box's twin, and updated against static.

    - the reading: the remaining error the probe measured (sign x the probed change since the
      reference touch, minus the correction LinuxCNC applied) equals the simulated truth (the
      run's drift since the reference touch minus that correction) within
      PROBE_RESOLUTION_NM, and the component sent sign x the probed change (within a count);
    - the box's answer ($M: verdict, reason, innovation, bias, variance) and its lines after
      every reading equal the twin's (hil.expect with the readings the component sent,
      codegen.estimator inside: bit-exact);
    - the chip (+``chip_um`` on the artifact) is refused (GATE), the offset does not move
      during its probe, and the box's lines are the same as if it had never been sent;
    - the tool's remaining error over the run (from the first probe on) is lower updated
      than static (the twin without readings, through the component's rules)."""
    problems: list[str] = []
    ref, probes = _probe_records(raw)
    out: dict = {"problems": problems, "rows": [], "resolution_nm": PROBE_RESOLUTION_NM}
    if ref is None or not probes:
        problems.append("probing: the reference touch or the probes did not run")
        return out
    ctx = _Probing(setup, scenario, static, ref,
                   {r["sample"]: r for r in raw.get("records", []) if "box" in r}, problems)
    meas: dict[int, list[tuple[int, int, int, bool]]] = {}
    for p in probes:
        out["rows"].append(ctx.row(p, meas))
    _against_twin(ctx, out, meas)
    _updated_against_static(ctx, out, probes[0]["sample"], len(probes))
    for r in out["rows"]:
        r.pop("reply", None)
    return out


class _Probing:
    """What every probe of one session is judged with."""

    def __init__(self, setup, scenario: Scenario, static: dict, ref: dict,
                 samples: dict[int, dict], problems: list[str]) -> None:
        self.setup, self.scenario, self.static, self.ref = setup, scenario, static, ref
        self.samples, self.problems = samples, problems
        self.ai = setup.spec.axis_names.index(dict(AXES)[PROBE_AXIS])
        self.drift = drift_nm(setup)
        self.period_s = setup.spec.sample_period_s
        self.chip = scenario.chip_sample()

    def row(self, p: dict, meas: dict) -> dict:
        """One probe: the reading against the truth, MEAS as sent, the answer and the pins."""
        k, problems = p["sample"], self.problems
        row: dict = {"sample": k, "time_h": k * self.period_s / 3600.0, "chip": k == self.chip,
                     "error": p.get("error", "")}
        if p.get("error"):
            problems.append(f"probe at sample {k}: LinuxCNC reported {p['error']}")
        dp_nm = self.measured(p, row)
        if len(p["meas_sent"]) != 1 or len(p["meas_replies"]) != 1:
            problems.append(f"probe at sample {k}: sent {p['meas_sent']}, box answered "
                            f"{p['meas_replies']} (one MEAS and one $M expected)")
            return row
        _, axis_s, nm_s, seq_s = p["meas_sent"][0].split()
        axis, nm, seq = int(axis_s), int(nm_s), int(seq_s)
        row.update({"reading_um": nm / 1000.0, "seq": seq})
        want_nm, box_seq = SIGN * dp_nm, self.samples[k]["box"]["seq"]
        if axis != self.ai or seq != box_seq or abs(nm - want_nm) > 1.0 + 1e-6:
            problems.append(f"probe at sample {k}: sent MEAS {axis} {nm} {seq}, expected axis "
                            f"{self.ai}, seq {box_seq}, {want_nm:.1f} nm (sign x the probed "
                            "change)")
        meas[k + 1] = [(axis, nm, k, False)]
        reply = protocol.decode(p["meas_replies"][0])
        row["reply"] = reply
        row.update({"applied": reply.applied, "reason": reply.reason,
                    "innovation_um": None if reply.innovation_nm is None
                    else reply.innovation_nm / 1000.0,
                    "bias_um": None if reply.bias_nm is None else reply.bias_nm / 1000.0})
        self.pins(p, reply)
        if k == self.chip:
            self.chip_refused(p, reply, row)
        return row

    def measured(self, p: dict, row: dict) -> float:
        """The remaining error the probe saw against the truth; the probed change (nm)."""
        k, letter = p["sample"], PROBE_AXIS
        # the probed position contains the external offset (LinuxCNC 2.9): its change is the
        # drift's, the remaining error is that minus the correction applied
        dp_nm = (p["probed_mm"][2] - self.ref["probed_mm"][2]) * 1e6
        corr_nm = SIGN * p["eoffset_before_mm"] * 1e6  # the correction LinuxCNC applied
        row["measured_um"] = (SIGN * dp_nm - corr_nm) / 1000.0  # the remaining error seen
        row["true_um"] = (self.drift[k] - corr_nm) / 1000.0
        row["static_um"] = (self.drift[k] - SIGN * self.static["offset_nm"][letter][k]) / 1000.0
        row["probe_s"] = p.get("probe_s")
        # a chip on the artifact is touched chip_um early: the tool looks that much shorter
        truth = row["true_um"] - (self.scenario.chip_um if k == self.chip else 0.0) * -SIGN
        off = abs(row["measured_um"] - truth) * 1000.0
        row["measure_ok"] = off <= PROBE_RESOLUTION_NM
        if not row["measure_ok"]:
            self.problems.append(f"probe at sample {k}: measured {row['measured_um']:.4f} um, "
                                 f"the true remaining error is {truth:.4f} um ({off:.1f} nm "
                                 f"apart, resolution {PROBE_RESOLUTION_NM:g} nm)")
        return dp_nm

    def pins(self, p: dict, reply: protocol.MeasReply) -> None:
        """The component's meas-* pins show the box's answer."""
        from thermal_comp.cnc import thermalcomp

        ok = (bool(p["meas-applied"]) == reply.applied
              and bool(p["meas-refused"]) != reply.applied
              and p["meas-reason"] == thermalcomp.MEAS_REASON_CODES.get(reply.reason or "", 0)
              and p["innovation-nm"] == (reply.innovation_nm or 0)
              and p["bias-nm"] == (reply.bias_nm or 0))
        if not ok:
            self.problems.append(f"probe at sample {p['sample']}: the component's pins "
                                 f"(applied {p['meas-applied']}, reason {p['meas-reason']}, "
                                 f"innovation {p['innovation-nm']}, bias {p['bias-nm']}) do "
                                 f"not show {p['meas_replies'][0]}")

    def chip_refused(self, p: dict, reply: protocol.MeasReply, row: dict) -> None:
        moved = abs(p["eoffset_after_mm"] - p["eoffset_before_mm"]) * 1e6
        row["chip_moved_nm"] = moved
        if reply.applied or reply.reason != "GATE" or moved > MOVED_NM:
            self.problems.append(f"the chip (+{self.scenario.chip_um:g} um) at sample "
                                 f"{p['sample']}: {p['meas_replies'][0]}, the offset moved "
                                 f"{moved:.3f} nm (want: refused, GATE, not moved)")


def _against_twin(ctx: _Probing, out: dict, meas: dict) -> None:
    """The box's answers and lines against the twin with the readings the component sent,
    and the twin without the chip's reading against it."""
    import numpy as np

    from thermal_comp.contract.fixed_point import CODE_MAX, CODE_MIN
    from thermal_comp.hil.expect import expect_session, sr_timeline

    setup, rows, problems, samples = ctx.setup, out["rows"], ctx.problems, ctx.samples
    feed = setup.feed
    codes = np.clip(np.asarray(feed.codes, dtype=np.int64), CODE_MIN, CODE_MAX)
    sr = sr_timeline(feed.n_samples, codes.shape[1], [])

    def twin(readings: dict):
        return expect_session(setup.twin, codes, feed.aux, sr, setup.output, zero_before=[0],
                              zero_at_powerup=setup.build.zero_at_powerup, meas=readings)

    upd = twin(meas)
    answered = [r for r in rows if "reply" in r]
    replies, twin_replies = [r["reply"] for r in answered], list(upd.meas_replies)
    out["twin_replies_equal"] = bool(replies) and replies == twin_replies
    if replies != twin_replies:
        bad = [(r["sample"], r["reply"], t) for r, t in zip(answered, twin_replies,
                                                             strict=False) if r["reply"] != t]
        problems.append(f"the box's answers differ from the twin's ({len(replies)} answers, "
                        f"{len(twin_replies)} from the twin, {len(bad)} differ; first: "
                        f"{bad[0] if bad else '-'})")
    mism = [k for k, r in samples.items()
            if r["box"]["corr_nm"] != [int(v) for v in upd.out_nm[k]]]
    out["box_vs_twin"] = {"compared": len(samples), "mismatches": len(mism)}
    if mism:
        problems.append(f"the box's lines differ from the twin's with the readings on "
                        f"{len(mism)} of {len(samples)} samples (first: {mism[0]})")
    chip = ctx.chip
    if chip is not None and chip + 1 in meas:
        without = twin({i: v for i, v in meas.items() if i != chip + 1})
        same = bool(np.array_equal(without.out_nm, upd.out_nm))
        out["chip_changed_nothing"] = same
        if not same:
            problems.append("the chip's reading changed the box's output (twin with and "
                            "without it differ)")


def _updated_against_static(ctx: _Probing, out: dict, first: int, n_probes: int) -> None:
    """The tool's remaining error, static against updated, from the first probe on."""
    letter, drift, samples, rows = PROBE_AXIS, ctx.drift, ctx.samples, out["rows"]
    ks = [k for k in sorted(samples) if k >= first]
    upd_err = [drift[k] - SIGN * samples[k]["eoffset_mm"][letter] * 1e6 for k in ks]
    st_err = [drift[k] - SIGN * ctx.static["offset_nm"][letter][k] for k in ks]

    def rms(v: list[float]) -> float:
        return math.sqrt(sum(x * x for x in v) / len(v)) / 1000.0 if v else float("nan")

    out.update({"static_rms_um": rms(st_err), "updated_rms_um": rms(upd_err),
                "static_max_um": max(map(abs, st_err), default=0.0) / 1000.0,
                "updated_max_um": max(map(abs, upd_err), default=0.0) / 1000.0,
                "samples": len(ks), "probes": n_probes,
                "applied": sum(1 for r in rows if r.get("applied")),
                "refused": sum(1 for r in rows if r.get("applied") is False)})
    if not out["updated_rms_um"] < out["static_rms_um"]:
        ctx.problems.append(f"updated ({out['updated_rms_um']:.3f} um RMS) is not better than "
                            f"static ({out['static_rms_um']:.3f} um RMS)")


def probe_table(pr: dict) -> list[str]:
    """The residual at each probe, static against updated (um, the box's sign)."""
    lines = ["", f"probing in service: Z, the reference touched right after ZERO, a probe every "
             f"{pr.get('every', '?')} samples (um; residual = drift since the reference - "
             "correction applied)",
             f"{'probe':>5s} {'time h':>7s} {'static':>8s} {'updated':>8s} {'true':>8s}"
             f"{'reading':>9s} {'innov.':>8s} {'bias':>8s}  answer",
             "-" * 78]
    for i, r in enumerate(pr.get("rows", [])):
        ans = ("applied" if r.get("applied") else f"refused {r.get('reason')}"
               if "applied" in r else "-") + ("  (chip +50 um)" if r.get("chip") else "")

        def f(v: float | None) -> str:
            return f"{v:8.3f}" if v is not None else f"{'-':>8s}"
        lines.append(f"{i:5d} {r['time_h']:7.2f} {f(r['static_um'])} {f(r['measured_um'])} "
                     f"{f(r['true_um'])} {f(r.get('reading_um'))} {f(r.get('innovation_um'))} "
                     f"{f(r.get('bias_um'))}  {ans}")
    if "static_rms_um" in pr:
        lines += [f"tool error from the first probe on ({pr['samples']} samples): static "
                  f"{pr['static_rms_um']:.3f} um RMS (max {pr['static_max_um']:.3f}), updated "
                  f"{pr['updated_rms_um']:.3f} um RMS (max {pr['updated_max_um']:.3f}); "
                  f"{pr['applied']} applied, {pr['refused']} refused",
                  f"each reading = the true remaining error within "
                  f"{pr['resolution_nm']:g} nm: "
                  f"{'yes' if all(r.get('measure_ok') for r in pr['rows']) else 'NO'}; "
                  f"box = twin (answers {'yes' if pr.get('twin_replies_equal') else 'NO'}, "
                  f"lines {pr['box_vs_twin']['compared'] - pr['box_vs_twin']['mismatches']}/"
                  f"{pr['box_vs_twin']['compared']})"
                  + ("" if "chip_changed_nothing" not in pr else
                     f"; the chip changed nothing: "
                     f"{'yes' if pr['chip_changed_nothing'] else 'NO'}")]
    return lines
