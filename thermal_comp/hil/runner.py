"""Drive a box through a run: feed samples with a window in flight, inject faults, collect lines.

The runner knows nothing about what the lines should contain (hil.expect and hil.checks do);
it only makes sure every feed command reaches the box in order and every line the box sends is
kept, per power-up ("session"), so the checks can look for lost, duplicated or reordered lines.

Pacing: time on the native board is virtual (one sample period per ``S`` command), so the
runner feeds as fast as the box answers. It keeps at most ``window`` samples in flight (fed but
not yet answered): enough to hide the pty round trip, small enough that a box that stops
answering is noticed within one window.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from thermal_comp.contract import protocol
from thermal_comp.hil.feed import Feed
from thermal_comp.hil.link import LinkTimeout, SerialLink
from thermal_comp.hil.native import BoxStartError
from thermal_comp.host.progress import progress


class Box(Protocol):
    """What the runner needs from a box (native process or QEMU)."""

    link: SerialLink

    def feed(self, data: bytes) -> None: ...
    def stop(self, timeout: float = 5.0) -> int: ...
    def kill(self) -> int: ...
    def alive(self) -> bool: ...
    def last_words(self) -> str: ...


# --- the script: what happens during a replay ---------------------------------------------
@dataclass(frozen=True)
class ChipFault:
    """Before sample ``at``: chip ``channel``'s fault status register becomes ``sr``."""

    at: int
    channel: int
    sr: int


@dataclass(frozen=True)
class CodeOverride:
    """Samples [start, stop): channel ``channel`` reads ``code`` instead of the run's value."""

    start: int
    stop: int
    channel: int
    code: int


@dataclass(frozen=True)
class CodeOffset:
    """Samples [start, stop): channel ``channel`` reads ``offset + per_sample * (i - start)``
    codes more than the run's value (a glitch, a slow drift)."""

    start: int
    stop: int
    channel: int
    offset: int
    per_sample: int = 0


@dataclass(frozen=True)
class ChannelSwap:
    """Samples [start, stop): channels ``a`` and ``b`` read each other's values (two sensor
    cables swapped at the box)."""

    start: int
    stop: int
    a: int
    b: int


@dataclass(frozen=True)
class SerialNoise:
    """Before sample ``at`` (all earlier lines received): ``data`` arrives on the box's UART.

    ``replies`` is how many reply lines (``$E``...) the host expects for it; the runner waits
    for them so the next sample line cannot overtake them.
    """

    at: int
    data: bytes
    replies: int


@dataclass(frozen=True)
class Zero:
    """Before sample ``at`` (all earlier lines received): the CNC side sends ``ZERO``; the
    runner waits for ``$OK,ZERO`` so the next sample is the first of the new reference."""

    at: int


@dataclass(frozen=True)
class Restart:
    """Before sample ``at``: the box resets and boots again (the process is killed and
    started). ``wdt_reset``: a warm reset (watchdog, brown-out): the retained memory survives
    and the box resumes where it was; otherwise a power cut: it boots cold. ``battery``: a
    cell on VBAT kept the retained memory through the cut (the box may be resumed, Resume);
    ``kept``: no battery, but the controller kept the box's state: it asked SNAP after the
    last sample before the cut (as the component does after every sample) and gives the
    block back with LOAD after the boot, so a Resume continues it as on a battery;
    ``off``: the samples [at, at + off) pass while it is off (nothing is fed, no line)."""

    at: int
    wdt_reset: bool = False
    battery: bool = False
    off: int = 0
    kept: bool = False


@dataclass(frozen=True)
class Resume:
    """Right after a ``Restart`` (at its ``at + off``): the CNC side sends ``RESUME <off>``
    and waits for ``$OK,RESUME`` (or ``$E,NO_STATE``: no battery kept the state)."""

    at: int
    off: int


@dataclass(frozen=True)
class Meas:
    """Before sample ``at`` (all earlier lines received): the CNC side sends a probe reading,
    ``MEAS <axis> <nm> <seq>`` (issue 42), of run sample ``seq`` (the runner sends the box's
    seq: the sample counted from the latest cold boot); it waits for the ``$M`` reply."""

    at: int
    axis: int
    nm: int
    seq: int


Event = (ChipFault | CodeOverride | CodeOffset | ChannelSwap | SerialNoise | Zero | Restart | Meas
         | Resume)
INPUT_EVENTS = (CodeOverride, CodeOffset, ChannelSwap)  # change what the chips read


@dataclass
class Session:
    """One power-up of the box: samples [first_sample, first_sample + n_fed) were fed to it."""

    first_sample: int
    wdt_reset: bool
    lines: list[bytes] = field(default_factory=list)
    n_fed: int = 0
    info: bytes = b""
    error: str = ""  # why the session ended early (timeout, crash), empty if it did not
    exit_code: int | None = None
    power_cut: bool = False  # ended by the runner (Restart, or after a timeout), not by Q
    zero_acks: list[bytes] = field(default_factory=list)  # replies to ZERO ($OK or $E), in order
    seq0: int = 0  # seq of its first sample line: 0 after a cold boot, kept after a warm one
    meas_replies: list[bytes] = field(default_factory=list)  # replies to MEAS ($M), in order
    battery: bool = False  # booted after a power cut with the retained memory kept (or loaded)
    resumed: bool = False  # RESUME accepted: it continues the session before the cut
    resume_acks: list[bytes] = field(default_factory=list)  # replies to RESUME, in order


@dataclass
class Capture:
    """Everything the box sent during a replay, per session, plus the inputs fed."""

    sessions: list[Session]
    codes_fed: list[list[int]]  # the channel codes actually fed per sample (after overrides)
    n_samples: int


# wdt_reset -> a started box; called with battery=True (keep the retained memory over a cold
# boot) only for a Restart(battery=True)
BoxFactory = Callable[..., Box]


def input_codes(codes: np.ndarray, events: Sequence[Event]) -> np.ndarray:
    """The chips' readings after the input events, in the order given (not clipped)."""
    out = np.array(codes, dtype=np.int64, copy=True)
    for e in events:
        if isinstance(e, CodeOverride):
            out[e.start:e.stop, e.channel] = e.code
        elif isinstance(e, CodeOffset):
            k = np.arange(max(e.stop - e.start, 0), dtype=np.int64)[:len(out[e.start:e.stop])]
            out[e.start:e.stop, e.channel] += e.offset + e.per_sample * k
        elif isinstance(e, ChannelSwap):
            out[e.start:e.stop, [e.a, e.b]] = out[e.start:e.stop, [e.b, e.a]]
    return out


def replay(feed: Feed, start_box: BoxFactory, events: Sequence[Event] = (), window: int = 256,
           chunk: int = 64, timeout: float = 20.0, quiet: bool = False,
           desc: str = "replay") -> Capture:
    """Feed every sample of ``feed`` to boxes made by ``start_box``; collect what they send."""
    n = feed.n_samples
    codes = input_codes(feed.codes, events)
    before: dict[int, list[Event]] = {}
    for e in events:
        if not isinstance(e, INPUT_EVENTS):
            before.setdefault(e.at, []).append(e)
    for e in events:
        if isinstance(e, Restart) and e.off:
            inside = [x for x in events if not isinstance(x, INPUT_EVENTS)
                      and e.at < x.at < e.at + e.off]
            if inside:
                raise ValueError(f"{inside[0]} falls while the box is off ({e})")
    run = _Replay(feed.feed_lines(codes), start_box, window, chunk, timeout)
    try:
        run.session.info = run.box.link.command("INFO", b"$I,", timeout)
        bar = iter(progress(range(n), desc=desc, total=n, quiet=quiet))
        for point in sorted({*before, n}):
            run.feed_until(point, bar)
            for e in before.get(point, []):
                run.apply(e, point)
        for _ in bar:  # exhaust: closes the progress bar
            pass
        run.sync()
        run.finish(kill=False)
    except (LinkTimeout, BoxStartError) as exc:
        # The box stopped answering, died while being fed, or did not boot again: the replay
        # ends here and the checks report it (with everything received so far).
        run.finish(kill=True)
        said = run.box.last_words()
        run.session.error = f"{exc} (the box said: {said})" if said else str(exc)
    except BaseException:
        run.box.kill()
        raise
    return Capture(run.sessions, codes.tolist(), n)


class _Replay:
    """The box being fed, its session, and the chip faults in force, during one ``replay``."""

    def __init__(self, lines: list[bytes], start_box: BoxFactory, window: int, chunk: int,
                 timeout: float) -> None:
        self.lines = lines
        self.start_box = start_box
        self.window = window
        self.chunk = chunk
        self.timeout = timeout
        self.sr_now: dict[int, int] = {}  # chip faults in force (physical: survive a restart)
        self.box = start_box(False)
        self.session = Session(0, False)
        self.sessions = [self.session]
        self.pos = 0  # the next sample to feed
        self.cold_start = 0  # the run sample of the latest cold boot (the box's seq 0)
        self.before_cut = 0  # cold_start before the latest restart (a RESUME goes back to it)

    def sync(self) -> None:
        """Wait until every sample fed to this session has been answered."""
        self.box.link.wait_prefixed(self.session.n_fed, self.timeout, f"sample line of sample "
                                    f"{self.session.first_sample + self.session.n_fed - 1}")

    def finish(self, kill: bool) -> None:
        s, b = self.session, self.box
        if kill:
            s.exit_code, s.power_cut = b.kill(), True
        else:
            s.exit_code = b.stop()
        s.lines = list(b.link.lines)

    def feed_until(self, point: int, bar: Iterator[int]) -> None:
        """Feed samples up to ``point`` in chunks, at most ``window`` of them in flight."""
        while self.pos < point:
            take = min(self.chunk, point - self.pos)
            self.box.link.wait_prefixed(self.session.n_fed + take - self.window, self.timeout,
                                        f"the line of sample {self.pos + take - self.window}")
            self.box.feed(b"".join(self.lines[self.pos:self.pos + take]))
            self.session.n_fed += take
            self.pos += take
            for _ in range(take):
                next(bar, None)

    def apply(self, e: Event, point: int) -> None:
        """An event that happens between samples (before sample ``point``)."""
        box, timeout = self.box, self.timeout
        if isinstance(e, ChipFault):
            self.sr_now[e.channel] = e.sr
            box.feed(f"F {e.channel} {e.sr:02x}\n".encode("ascii"))
        elif isinstance(e, SerialNoise):
            self.sync()
            start = box.link.count()
            box.link.write(e.data)
            box.link.wait_count(start + e.replies, timeout,
                                f"{e.replies} replies to serial noise before sample {point}")
        elif isinstance(e, Zero):
            self.sync()
            self.session.zero_acks.append(
                self.ask(b"ZERO\r\n", (b"$OK,ZERO,", b"$E,"), f"ZERO before sample {point}"))
        elif isinstance(e, Meas):
            self.sync()
            seq = (e.seq - self.cold_start) % 2**32
            self.session.meas_replies.append(
                self.ask(f"MEAS {e.axis} {e.nm} {seq}\r\n".encode("ascii"), (b"$M,", b"$E,"),
                         f"MEAS before sample {point}"))
        elif isinstance(e, Restart):
            self.sync()  # the power cut falls between two samples, not inside one
            block = self.snapshot(point) if e.kept else b""
            self.restart(point, e.wdt_reset, e.battery, e.off)
            if e.kept:
                self.load(block, point + e.off)
        elif isinstance(e, Resume):
            s = self.session
            if len(self.sessions) < 2 or s.n_fed or s.first_sample != point:
                raise ValueError(f"{e}: RESUME goes right after a Restart")
            reply = self.ask(f"RESUME {e.off}\r\n".encode("ascii"), (b"$OK,RESUME,", b"$E,"),
                             f"RESUME before sample {point}")
            s.resume_acks.append(reply)
            if reply.startswith(b"$OK,"):
                s.resumed = True
                self.cold_start = self.before_cut  # the old power-up's sequence goes on
                s.seq0 = point - self.cold_start

    def ask(self, command: bytes, replies: tuple[bytes, ...], what: str) -> bytes:
        """Send a command and wait for the first line after it that starts with one of
        ``replies`` (the box's answer); returns it."""
        link = self.box.link
        start = link.count()
        link.write(command)

        def answered(lines: list[bytes]) -> bool:
            return any(ln.startswith(replies) for ln in lines[start:])

        link.wait_for(answered, self.timeout, f"reply to {what}")
        return next(ln for ln in link.lines[start:] if ln.startswith(replies))

    def snapshot(self, point: int) -> bytes:
        """SNAP: the block the box keeps, put together from its $B pieces."""
        link = self.box.link
        start = link.count()
        self.ask(b"SNAP\r\n", (b"$OK,SNAP,", b"$E,"), f"SNAP before sample {point}")
        pieces = [protocol.decode(ln) for ln in link.lines[start:] if ln.startswith(b"$B,")]
        return protocol.assemble_block([p for p in pieces if isinstance(p, protocol.BlockPiece)])

    def load(self, block: bytes, point: int) -> None:
        """LOAD: the block back into the freshly booted box, piece by piece."""
        for line in protocol.encode_load(block):
            reply = self.ask(line, (b"$OK,LOAD,", b"$E,"), f"LOAD before sample {point}")
            if not reply.startswith(b"$OK,"):
                raise BoxStartError(f"LOAD refused: {reply.decode(errors='replace')}")
        self.session.battery = True

    def restart(self, point: int, wdt_reset: bool, battery: bool = False, off: int = 0) -> None:
        """Power cut and boot: a new session; the chips' faults are still there. ``off``
        samples pass unfed while the box is off."""
        self.finish(kill=True)
        self.before_cut = self.cold_start
        if not wdt_reset:
            self.cold_start = point + off
        self.box = (self.start_box(wdt_reset, battery=True) if battery
                    else self.start_box(wdt_reset))
        self.pos += off
        point += off
        self.session = Session(point, wdt_reset, seq0=point - self.cold_start if wdt_reset
                               else 0, battery=battery)
        self.sessions.append(self.session)
        self.session.info = self.box.link.command("INFO", b"$I,", self.timeout)
        for ch, value in sorted(self.sr_now.items()):
            if value:
                self.box.feed(f"F {ch} {value:02x}\n".encode("ascii"))
