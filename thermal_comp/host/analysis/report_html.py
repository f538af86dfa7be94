"""`host report`'s page: the Jinja2 template and the texts it fills in."""

from __future__ import annotations

import base64
from pathlib import Path

from thermal_comp.host.analysis.metrology import (
    VIF_NOT_IDENTIFIABLE,
)
from thermal_comp.host.analysis.report_data import SECTIONS, Report, fmt_value

# ---------------------------------------------------------------- HTML

TEMPLATES = Path(__file__).with_name("templates")


def _status_counts_text(counts: dict | None) -> str:
    if not counts:
        return ""
    text = " Status bits the box raised: " + ", ".join(
        f"{name} on {n} sample{'s' if n != 1 else ''}" for name, n in counts.items()) + "."
    if "EXTRAP" in counts:
        text += (" EXTRAP: a reading beyond its training window, so the correction is an "
                 "extrapolation (still applied).")
    return text


def _beyond_text(rows: list[dict] | None) -> str:
    if rows is None:
        return "not stored in this model"
    if not rows:
        return "none"
    return ", ".join(
        f"{r['input']} {'+' if r['run_max'] > r['train_max'] else '−'}"
        + (f"{100 * r['beyond_share']:.0f} %" if r["beyond_share"] is not None
           else f"{r['beyond']:.3g}")
        + f" ({r['samples_outside_pct']:.0f} % of the run)" for r in rows)


def _span_text(values: list[float] | None) -> str:
    """A gain across the folds: ``lowest … highest (n folds)``, or — without folds."""
    if not values:
        return "—"
    if len(values) == 1:
        return f"{values[0]:.3f} (1 fold)"
    return f"{min(values):.3f} … {max(values):.3f} ({len(values)} folds)"


def _duration_text(seconds: float) -> str:
    """A time constant as a reader thinks of it: 900 s, 1 h, 4 h."""
    if seconds >= 3600 and seconds % 1800 == 0:
        return f"{seconds / 3600:g} h"
    return f"{seconds:g} s"


def _environment():
    import jinja2

    env = jinja2.Environment(loader=jinja2.FileSystemLoader(str(TEMPLATES)),
                             autoescape=jinja2.select_autoescape(["html", "j2"]),
                             trim_blocks=False)
    env.filters["num"] = lambda v, digits=2: fmt_value(v, digits)
    env.filters["nm"] = lambda v: fmt_value(None if v is None else v * 1000, 3)
    env.filters["span"] = _span_text
    env.filters["duration"] = _duration_text
    env.filters["mode"] = lambda gain, tau: next(
        (m["amplitude_um_per_k"] for m in gain["modes"] if m["tau_s"] == tau), None)
    env.globals["vif_limit"] = VIF_NOT_IDENTIFIABLE
    env.globals["status_counts"] = _status_counts_text
    env.globals["hil_checks"] = lambda hil: ", ".join(
        f"{k} {'passed' if v else 'FAILED'}" for k, v in (hil.get("checks") or {}).items()) \
        or "—"
    return env


def render_html(model: dict, report: Report) -> str:
    """The page, from ``templates/report.html.j2`` (jinja2, autoescaped; captions are built
    escaped and marked safe)."""
    summary = report.summary
    models = list(dict.fromkeys(m for per in summary["runs"].values() for a in per.values()
                                for m in a["residual_rms_um"]))
    sections = []
    for key, heading in SECTIONS:
        figs = [f for f in report.figures if f.section == key]
        if figs:
            sections.append({"heading": heading, "figures": [{
                "stem": Path(f.file).stem, "file": f.file, "title": f.title,
                "caption": f.caption, "groups": f.groups,
                "data": base64.b64encode((report.out_dir / f.file).read_bytes()).decode("ascii"),
            } for f in figs]})
    context = {
        "model": model, "summary": summary, "models": models, "sections": sections,
        "validations": sorted({r["validation"] for r in summary["axes"] if r.get("validation")}),
        "beyond": {name: _beyond_text(rows)
                   for name, rows in summary.get("outside_training", {}).items()},
        "coefficients": summary.get("coefficients") or [],
        "wiring": summary.get("wiring") or [],
        "locations_given": summary.get("locations_given", False),
    }
    return _environment().get_template("report.html.j2").render(**context)
