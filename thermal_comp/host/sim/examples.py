"""Regenerate the committed example runs: ``make examples``.

Four protocols of paper 002 / paper 000 on the same simulated machine (machine seed 0), each a
different day (its own seed), 8 h running + 8 h cooling sampled every minute, 12 thermocouples
plus the shop air. The effects that any real test of that length has are on: the unmeasured
spindle shaft (``lag``) and the shop's daily cycle (``ambient``). The demo trains on
``sim_constant`` + ``sim_step`` and judges on ``sim_random``.
"""

from __future__ import annotations

import sys
from pathlib import Path

from thermal_comp.host.sim.simulator import SimConfig, simulate, write_simulation
from thermal_comp.host.sim.spindle_programs import build_program

MAX_RPM = 8000.0
HOURS, COOL_HOURS = 8.0, 8.0
DT_S = 60.0
N_SENSORS = 12
EFFECTS = ("lag", "ambient")
PRECISION = 6
EXAMPLES = (("sim_constant", "constant", 1), ("sim_step", "step", 2),
            ("sim_random", "random", 3), ("sim_sine", "sine", 4))


def generate(out_dir: str | Path) -> list[Path]:
    """Write every example run and its truth sidecar into out_dir; returns the CSV paths."""
    out_dir = Path(out_dir)
    paths = []
    for name, protocol, seed in EXAMPLES:
        program = build_program(protocol, MAX_RPM, HOURS, COOL_HOURS, seed=seed)
        sim = simulate(program, SimConfig(n_sensors=N_SENSORS, dt_s=DT_S, seed=seed,
                                          effects=EFFECTS))
        path = out_dir / f"{name}.csv"
        write_simulation(sim, path, precision=PRECISION)
        paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print("usage: python -m thermal_comp.host.sim.examples OUT_DIR", file=sys.stderr)
        return 2
    for path in generate(argv[0]):
        print(f"wrote {path} ({path.stat().st_size / 1024:.0f} kB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
