"""How often does a damaged `$C` line pass the decoder as a valid sample with another value?

Issue 41 (frame check decision, docs/linuxcnc.md "Frame check"): builds realistic sample lines
with ``contract.protocol``'s encoders (3 axes, 8 channels, values as the box sends them),
damages each once in one of several ways and asks ``contract.protocol.decode`` (the decoder the
HIL, ``host monitor`` and the LinuxCNC component share) whether the result is still a valid
sample. An *escape* is a damaged line that decodes as a sample whose corrections differ from the
original's (``escape_value``); ``escape_any`` also counts lines that decode with only the seq,
status or temperature codes changed.

Kinds of damage (one per trial, position uniform over the line without its CR LF):

- ``insert``: one byte inserted, drawn from the line's own alphabet (digits, ``,`` ``-``
  and the hex digits A-F): the worst case, since any other byte fails the printable/format
  check; ``insert_any`` draws it from all 256 byte values;
- ``delete``: one byte removed;
- ``substitute``: one byte replaced by another of the line's alphabet (``substitute_any``: by
  any other byte value);
- ``burst``: 2 to 8 consecutive bytes replaced by bytes of the line's alphabet (a noise burst
  longer than CRC-16's guaranteed 16 bits);
- ``bitflip``: 1 to 3 random bit flips anywhere in the line (CRC-16/CCITT detects all of
  these at these lengths: the control).

Run: ``.venv/bin/python scripts/frame_escape.py --trials 2000000`` (about a minute per kind
on one core). ``--json`` prints the table as JSON. The rates come with a 95 % Poisson interval.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from thermal_comp.contract import protocol  # noqa: E402

ALPHABET = np.frombuffer(b"0123456789,-ABCDEF", dtype=np.uint8)
KINDS = ("insert", "insert_any", "delete", "substitute", "substitute_any", "burst", "bitflip")
N_TEMPLATES = 4096


def templates(rng: np.random.Generator, n: int) -> list[tuple[bytes, protocol.Sample]]:
    """Sample lines as the box writes them (without CR LF), with their corrections.

    3 axes drifting by up to ±60 µm, 8 thermocouples between 15 and 45 °C (1/128 °C codes),
    seq anywhere in a long run, status 0, REFERENCED, EXTRAP or SLEW.
    """
    out = []
    statuses = [0, int(protocol.Status.REFERENCED), int(protocol.Status.EXTRAP),
                int(protocol.Status.SLEW | protocol.Status.REFERENCED)]
    for _ in range(n):
        seq = int(rng.integers(0, 2_000_000))
        status = statuses[int(rng.integers(0, len(statuses)))]
        corr = tuple(int(v) for v in rng.integers(-60_000, 60_001, size=3))
        codes = [int(v) for v in rng.integers(15 * 128, 45 * 128, size=8)]
        line = protocol.encode_sample(seq, status, corr, codes).rstrip(b"\r\n")
        out.append((line, protocol.Sample(seq, status, corr, tuple(codes))))
    return out


def damage(kind: str, line: bytes, rng: np.random.Generator) -> bytes:
    n = len(line)
    if kind == "insert":
        i = int(rng.integers(0, n + 1))
        return line[:i] + bytes([int(rng.choice(ALPHABET))]) + line[i:]
    if kind == "insert_any":
        i = int(rng.integers(0, n + 1))
        return line[:i] + bytes([int(rng.integers(0, 256))]) + line[i:]
    if kind == "delete":
        i = int(rng.integers(0, n))
        return line[:i] + line[i + 1:]
    if kind in ("substitute", "substitute_any"):
        i = int(rng.integers(0, n))
        while True:
            b = int(rng.choice(ALPHABET)) if kind == "substitute" else int(rng.integers(0, 256))
            if b != line[i]:
                return line[:i] + bytes([b]) + line[i + 1:]
    if kind == "burst":
        k = int(rng.integers(2, 9))
        i = int(rng.integers(0, n - k + 1))
        return line[:i] + bytes(rng.choice(ALPHABET, size=k).tolist()) + line[i + k:]
    if kind == "bitflip":
        buf = bytearray(line)
        for bit in rng.choice(8 * n, size=int(rng.integers(1, 4)), replace=False):
            buf[int(bit) // 8] ^= 1 << (int(bit) % 8)
        return bytes(buf)
    raise ValueError(kind)


def poisson_95(k: int) -> tuple[float, float]:
    """95 % interval of a Poisson count k (Wilson-Hilferty / exact-enough for reporting)."""
    lo = 0.0 if k == 0 else k * (1 - 1 / (9 * k) - 1.96 / (3 * math.sqrt(k))) ** 3
    k1 = k + 1
    hi = k1 * (1 - 1 / (9 * k1) + 1.96 / (3 * math.sqrt(k1))) ** 3
    return lo, hi


def measure(kind: str, trials: int, seed: int) -> dict:
    rng = np.random.default_rng([seed, KINDS.index(kind)])
    lines = templates(rng, N_TEMPLATES)
    pick = rng.integers(0, N_TEMPLATES, size=trials)
    escape_any = escape_value = 0
    largest_nm = 0
    examples: list[str] = []
    line_re, crc16 = protocol.LINE_RE, protocol.crc16
    t0 = time.monotonic()
    for t in range(trials):
        line, original = lines[pick[t]]
        bad = damage(kind, line, rng)
        # the decoder's own first two checks, inlined for speed; anything passing them goes
        # through protocol.decode itself, which has the last word
        m = line_re.fullmatch(bad)
        if m is None or int(m.group(2), 16) != crc16(m.group(1)):
            continue
        try:
            msg = protocol.decode(bad)
        except protocol.ProtocolError:
            continue
        if not isinstance(msg, protocol.Sample) or msg == original:
            continue  # e.g. a line feed inserted at the end: the same sample
        escape_any += 1
        corr = original.corrections_nm
        if msg.corrections_nm != corr:
            escape_value += 1
            if len(msg.corrections_nm) == len(corr):
                d = max(abs(a - b) for a, b in zip(msg.corrections_nm, corr, strict=True))
            else:
                d = max(abs(v) for v in msg.corrections_nm + corr)
            largest_nm = max(largest_nm, d)
            if len(examples) < 3:
                examples.append(f"{line.decode()} -> {bad.decode('ascii', 'replace')}")
    lo, hi = poisson_95(escape_value)
    return {"kind": kind, "trials": trials, "escape_any": escape_any,
            "escape_value": escape_value, "rate_per_million": 1e6 * escape_value / trials,
            "rate_95_per_million": [1e6 * lo / trials, 1e6 * hi / trials],
            "largest_change_nm": largest_nm, "examples": examples,
            "seconds": time.monotonic() - t0}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=2_000_000, help="trials per kind")
    ap.add_argument("--kinds", default=",".join(KINDS), help="comma-separated subset")
    ap.add_argument("--seed", type=int, default=41)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rows = []
    for kind in args.kinds.split(","):
        if kind not in KINDS:
            ap.error(f"unknown kind {kind!r} (known: {', '.join(KINDS)})")
        rows.append(measure(kind, args.trials, args.seed))
        if not args.json:
            r = rows[-1]
            lo, hi = r["rate_95_per_million"]
            print(f"{kind:15s} {r['trials']:>10,d} trials  {r['escape_value']:>5d} escaped with "
                  f"another value ({r['escape_any']:>5d} valid)  {r['rate_per_million']:6.2f} "
                  f"per million [{lo:.2f}, {hi:.2f}]  largest change "
                  f"{r['largest_change_nm'] / 1000:9.1f} um  ({r['seconds']:.0f} s)", flush=True)
    if args.json:
        print(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
