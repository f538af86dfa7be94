"""What a `make cnc` / `make probe` session injects and where it runs (docs/linuxcnc.md): the
scenario, the staged files' places, the model the session's box carries."""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

from thermal_comp.contract import checkout
from thermal_comp.host.sim import ThermalTestPlan

PACKAGE = Path(__file__).resolve().parents[1]  # thermal_comp/, in a checkout or a wheel
ROOT = checkout.root()  # build/, examples/, firmware/: the checkout's
CONFIG_DIR = PACKAGE / "cnc" / "config"
USER = os.environ.get("THERMAL_CNC_USER", "thermal-cnc")
LOCK = Path(tempfile.gettempdir()) / "thermal-cnc-linuxcnc.lock"
LINUXCNC = "/usr/bin/linuxcnc"
SYSTEM_PYTHON = "/usr/bin/python3"
AXES = [("x", "dx_um"), ("y", "dy_um"), ("z", "dz_um")]  # as cnc/config/thermalcomp.conf
SIGN = -1
START_MDI = "G90 G0 X0 Y0 Z-50"
HOLD_BITS = (1 << 0) | (1 << 1) | (1 << 9) | (1 << 12)  # MODEL_BAD, HOLD, NO_DATA, IMPLAUSIBLE
MOVED_NM = 0.01  # "did not move": LinuxCNC's planner settles within hundredths of a nm
TRAIN_RUN = ROOT / "examples" / "sim_step.csv"
REPLAY_RUN = ROOT / "examples" / "sim_random.csv"
PROBE_AXIS = "z"  # the axis the probe measures ([probe] axis in thermalcomp.conf)


class CncError(RuntimeError):
    """LinuxCNC is missing, could not be run, or the session did not complete."""


@dataclass
class Scenario:
    """What the session injects, by sample index of the replayed run.

    Besides the faults the component holds on (open thermocouple, stale stream, corrupted
    line, machine off/on, enable off/on, ZERO), the controller events of issue 41's rule,
    each judged against the clean run (``fault_rows``): a forged CRC-valid line
    (``forged_at``: after that sample, every correction +``forged_delta_um``), noise on the
    wire (``garbage_at``: random bytes and a 16 KiB run without a newline, before that
    sample), a dropped and restored link (``reconnect_at`` for ``reconnect_samples``
    samples), a watchdog restart (``wdt_at``: the box killed and started with
    ``--wdt-reset`` on its retained memory) and power cuts (``power_cuts``: (sample, samples
    until the operator's ZERO) each; the box boots cold, NO_REF)."""

    n_samples: int = 961
    open_at: int | None = 200
    open_stop: int = 260
    open_channel: int = 0
    stale_at: int | None = 350
    bad_at: int | None = 420
    off_at: int | None = 500
    off_samples: int = 5
    disable_at: int | None = 600
    disable_samples: int = 5
    zero_at: int | None = 700
    forged_at: int | None = 120
    forged_delta_um: float = 60.0
    garbage_at: int | None = 300
    reconnect_at: int | None = 380
    reconnect_samples: int = 2
    wdt_at: int | None = 450
    power_cuts: tuple[tuple[int, int], ...] = ((800, 1), (880, 3))
    zero_at_start: bool = True  # a start-referenced box holds (NO_REF) until the job's ZERO
    stale_period_s: float = 0.1  # the component's stale clock in the time-compressed replay
    stale_periods: float = 3.0
    testplans: tuple[ThermalTestPlan, ...] = ()  # run after the replay, in AUTO (linuxcnc)
    # probing in service (issue 42): the probing subroutine every probe_every samples (from
    # sample probe_every on), a chip on the artifact (+chip_um) at probe number chip_probe
    probe_every: int | None = None
    chip_probe: int | None = None
    chip_um: float = 50.0

    def probe_samples(self) -> list[int]:
        if not self.probe_every:
            return []
        # not after the last sample: its answer would act on no sample
        return list(range(self.probe_every, self.n_samples - 1, self.probe_every))

    def chip_sample(self) -> int | None:
        at = self.probe_samples()
        return at[self.chip_probe] if self.chip_probe is not None and \
            self.chip_probe < len(at) else None

    def events(self) -> dict:
        ev: dict = {}
        if self.open_at is not None:
            ev["open"] = {"at": self.open_at, "stop": self.open_stop,
                          "channel": self.open_channel}
        if self.stale_at is not None:
            ev["stale"] = {"at": self.stale_at,
                           "pause_s": 3 * self.stale_period_s * self.stale_periods}
        if self.bad_at is not None:
            ev["bad_line"] = {"at": self.bad_at}
        if self.off_at is not None:
            ev["machine_off"] = {"at": self.off_at, "samples": self.off_samples}
        if self.disable_at is not None:
            ev["disable"] = {"at": self.disable_at, "samples": self.disable_samples}
        if self.zero_at is not None:
            ev["zero"] = {"at": self.zero_at}
        if self.forged_at is not None:
            ev["forged"] = {"at": self.forged_at,
                            "delta_nm": round(self.forged_delta_um * 1000.0)}
        if self.garbage_at is not None:
            ev["garbage"] = {"at": self.garbage_at, "seed": 41}
        if self.reconnect_at is not None:
            ev["reconnect"] = {"at": self.reconnect_at, "samples": self.reconnect_samples}
        if self.wdt_at is not None:
            ev["wdt_restart"] = {"at": self.wdt_at}
        out = {k: v for k, v in ev.items() if _inside(v, self.n_samples)}
        cuts = [{"at": at, "zero_after": after} for at, after in self.power_cuts
                if at + after < self.n_samples]
        if cuts:
            out["power_cut"] = cuts
        return out

    def controller_events(self) -> list[tuple[str, int]]:
        """(scenario name, sample) of each event judged by the rule, in order."""
        ev = self.events()
        named = [("forged line", "forged"), ("garbage on the wire", "garbage"),
                 ("stale stream", "stale"), ("reconnect", "reconnect"),
                 ("corrupted line", "bad_line"), ("watchdog restart", "wdt_restart")]
        out = [(name, int(ev[key]["at"])) for name, key in named if key in ev]
        out += [(f"power cut (ZERO after {c['zero_after']})", int(c["at"]))
                for c in ev.get("power_cut", [])]
        return sorted(out, key=lambda e: e[1])


def campaign_scenario() -> Scenario:
    """Every controller event of the fault campaign (hil/faults.py: ``make faults``) on the
    whole replay, without the test programs: run it with ``run_session`` and turn the result
    into rows with ``fault_rows``."""
    return Scenario(testplans=())


def probe_scenario(n_samples: int = 961, every: int = 60, chip_probe: int | None = 8
                   ) -> Scenario:
    """In-service probing (``make probe``): the job's ZERO and reference touch, then the
    probing subroutine every ``every`` samples (60: hourly in the replayed run), a chip on
    the artifact at probe number ``chip_probe``; no faults, no test programs."""
    return Scenario(n_samples=n_samples, open_at=None, stale_at=None, bad_at=None,
                    off_at=None, disable_at=None, zero_at=None, forged_at=None,
                    garbage_at=None, reconnect_at=None, wdt_at=None, power_cuts=(),
                    probe_every=every, chip_probe=chip_probe)


# The session's model carries this estimator block when it probes (docs/service.md): train's
# fields, set here rather than derived (the example model is not fitted by host train). q:
# the wander of this model's residual on the replayed day is about 4 um^2 per hour.
SESSION_SERVICE = {"q_um2_per_h": 4.0, "probe_noise_um": 0.5, "gate_sigma": 4.0,
                   "gate_floor_um": 3.0, "p_max_um2": 100.0,
                   "why": "make probe: q 4 um^2/h (this example model's residual on the "
                          "replayed day wanders by about 2 um per hour); p_max 100 um^2 keeps "
                          "the gate below 41 um, so a +50 um chip is refused"}


def _inside(event: dict, n: int) -> bool:
    return int(event["at"]) < n


def drift_nm(setup, letter: str = PROBE_AXIS) -> list[float]:
    """The machine's thermal displacement of the tool along the axis at each sample (nm, the
    box's sign: tool relative to work), since the run's first sample: the replayed run's
    measured displacement, which the simulated artifact's surface follows."""
    box_axis = dict(AXES)[letter]
    d = [float(v) for v in setup.feed.measured[box_axis]]
    return [(v - d[0]) * 1000.0 for v in d]
