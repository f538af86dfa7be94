"""What `host monitor` knows about the box (``MonitorState``): its INFO, the latest sample,
the flags and their names, the fault history, the link; the views only read it."""

from __future__ import annotations

from dataclasses import dataclass, field

from thermal_comp.contract import protocol
from thermal_comp.contract.errors import InputError
from thermal_comp.host.box.history import FaultHistory

STALE_PERIODS = 2.0  # no line for more than this many expected intervals: STALE

SIGN_NOTE = ("sign: a correction is the box's prediction of the thermal displacement, in the "
             "sign of the displacement measured in the thermal test (compensated = measured − "
             "correction): the offset to apply is −correction")

# flags that mean some channel is faulted: ask STATUS which one
FAULT_FLAGS = {"HOLD", "RANGE", "OPEN", "TC_FAULT", "AUX_FAULT", "NO_DATA", "IMPLAUSIBLE",
                "BEYOND"}
# the flags a channel's fault word explains, and the fault word's bits each one stands for
CHANNEL_FLAGS = {"TC_FAULT": {"OVUV", "TCLOW", "TCHIGH", "CJLOW", "CJHIGH", "TCRANGE",
                               "CJRANGE"}, "OPEN": {"OPEN"}, "RANGE": {"RANGE"},
                  "IMPLAUSIBLE": {"IMPLAUSIBLE"}, "BEYOND": {"BEYOND"}}


class MonitorError(InputError):
    """Bad monitor input (unreadable model, a log file with another layout, a port that
    cannot be opened at start)."""


def status_names(status: int) -> list[str]:
    """Names of the bits set in a status word; a bit newer than this contract (a newer box)
    shows as ``bit<n>``, never as an error."""
    named = len(protocol.STATUS_BITS)
    return protocol.status_names(status) + [f"bit{b}" for b in range(named, 16)
                                             if status >> b & 1]


def channel_fault_names(word: int) -> list[str]:
    """Names of a STATUS per-channel fault word's bits (MAX31856 SR, then the box's own)."""
    return [f.name for f in protocol.ChannelFault if word & f.value and f.name]


@dataclass
class MonitorState:
    """Everything the display shows; updated by the reader, rendered by ``render``."""

    port: str
    info: protocol.Info | None = None
    expected_hash: str | None = None
    sample: protocol.Sample | None = None
    status_report: protocol.StatusReport | None = None
    samples: int = 0
    bad_lines: int = 0
    last_bad: str = ""
    seq_gaps: int = 0
    reconnects: int = 0
    withheld: int = 0  # samples not shown because the device had not identified itself
    connected: bool = False
    last_rx: float | None = None  # any valid line
    last_sample_rx: float | None = None
    seq_step: int = 1  # seq advance between the last two samples (RATE n: n)
    stale: bool = False
    messages: list[str] = field(default_factory=list)
    # sensor -> (window_lo, window_hi) codes from model.json (codegen's EXTRAP windows); used
    # only while the box reports that model's hash, to name the channels behind EXTRAP
    windows: dict[str, tuple[int, int]] = field(default_factory=dict)
    # axis -> thermocouples its terms read (from --model): names the axes a fault holds
    axis_inputs: dict[str, list[str]] = field(default_factory=dict)
    history: FaultHistory = field(default_factory=FaultHistory)
    # axis -> the model's promise (model.json metrics.promise, the wording host train and the
    # report use): shown while the box runs that model
    promises: dict[str, str] = field(default_factory=dict)
    period_hint_s: float | None = None  # the last INFO's period: kept while INFO is re-asked
    disconnected_at: float | None = None  # monotonic time the port was lost

    @property
    def hash_ok(self) -> bool | None:
        if self.expected_hash is None or self.info is None:
            return None
        return self.info.model_hash == self.expected_hash

    def axis_names(self, n: int) -> list[str]:
        names = list(self.info.axes) if self.info else []
        return names[:n] + [f"axis{i}" for i in range(len(names), n)]

    def channel_names(self, n: int) -> list[str]:
        names = [c.sensor for c in self.info.channels] if self.info else []
        return names[:n] + [f"ch{i}" for i in range(len(names), n)]

    @property
    def flags(self) -> list[str]:
        return status_names(self.sample.status) if self.sample is not None else []

    def period_s(self) -> float | None:
        """The box's sample period (INFO), or the last one known while INFO is asked again
        (after a reconnect): the age and STALE keep counting when the box has gone away."""
        if self.info and self.info.period_ms:
            return self.info.period_ms / 1000.0
        return self.period_hint_s

    def faulted_channels(self) -> dict[str, list[str]]:
        """Channel name -> fault names, from the latest STATUS reply, while the current
        sample still raises a fault flag (a cleared fault clears the map)."""
        rep, s = self.status_report, self.sample
        if rep is None or s is None or not (set(self.flags) & FAULT_FLAGS):
            return {}
        names = self.channel_names(max(len(rep.channel_faults), len(s.temp_codes)))
        return {names[i]: channel_fault_names(w) or [f"0x{w:04X}"]
                for i, w in enumerate(rep.channel_faults) if w}

    def unnamed_channel_faults(self) -> list[str]:
        """Channel-fault flags of the current sample whose channel no STATUS reply has named
        yet (the reply is on its way): every channel is then suspect."""
        named = {f for faults in self.faulted_channels().values() for f in faults}
        return [n for n in self.flags if n in CHANNEL_FLAGS and not CHANNEL_FLAGS[n] & named]

    def invalid_channels(self) -> dict[str, str]:
        """Channel name -> why its reading is not a temperature: its faults from STATUS, or,
        while a channel-fault flag is up and STATUS has not named the channel yet, every
        channel ("OPEN?": one of them is open, which one is not known yet)."""
        s = self.sample
        if s is None:
            return {}
        out = {n: "/".join(f) for n, f in self.faulted_channels().items()}
        unnamed = self.unnamed_channel_faults()
        if unnamed:
            for n in self.channel_names(len(s.temp_codes)):
                out.setdefault(n, "/".join(f"{u}?" for u in unnamed))
        return out

    def held_axes(self) -> list[str] | None:
        """Axes that read a faulted channel (so hold), when --model says which axes read
        what and the box runs that model; None when it cannot be told."""
        if "HOLD" not in self.flags:
            return []
        faulted = set(self.faulted_channels())
        if not faulted or not self.axis_inputs or self.hash_ok is not True:
            return None
        return [a for a, inputs in self.axis_inputs.items() if faulted & set(inputs)]

    def zero_seq(self) -> int | None:
        rep = self.status_report
        return getattr(rep, "zero_seq", None) if rep is not None else None

    def beyond_training(self) -> list[str]:
        """Channels of the current sample outside their training window (named only when the
        box runs the model.json the windows came from)."""
        s = self.sample
        if s is None or not self.windows or self.hash_ok is not True:
            return []
        names = self.channel_names(len(s.temp_codes))
        return [n for n, code in zip(names, s.temp_codes, strict=True)
                if n in self.windows and not self.windows[n][0] <= code <= self.windows[n][1]]

    def silence_s(self, now: float) -> float | None:
        return None if self.last_sample_rx is None else now - self.last_sample_rx

    def stale_after_s(self) -> float | None:
        period = self.period_s()
        return None if period is None else STALE_PERIODS * period * max(1, self.seq_step)


def flag_labels(state: MonitorState) -> list[str]:
    """The status flags of the current sample, each named with what it concerns: EXTRAP and
    the channel faults with their channels, HOLD with its axes, REFERENCED with its ZERO (in
    the order of ``state.flags``)."""
    assert state.sample is not None
    names = state.flags
    faulted = state.faulted_channels()
    out: list[str] = []
    for n in names:
        if n == "EXTRAP":
            beyond = state.beyond_training()
            out.append(f"EXTRAP({'+'.join(beyond)})" if beyond else n)
        elif n == "HOLD":
            held = state.held_axes()
            chans = "+".join(faulted)
            out.append(f"HOLD({'+'.join(held)})" if held else
                       f"HOLD(axes reading {chans})" if chans else n)
        elif n in CHANNEL_FLAGS:
            chans = [c for c, f in faulted.items() if CHANNEL_FLAGS[n] & set(f)]
            out.append(f"{n}({'+'.join(chans)})" if chans else n)
        elif n == "REFERENCED" and state.zero_seq() is not None:
            out.append(f"REFERENCED(since #{state.zero_seq()})")
        else:
            out.append(n)
    return out


def flags_text(state: MonitorState, sep: str) -> str:
    return sep.join(flag_labels(state)) or "ok"


def hash_line(state: MonitorState) -> str:
    if state.info is None:
        return "model: (no INFO reply yet)"
    info = state.info
    # what matters first: on a narrow terminal the end of the line is what is cut
    text = f"model {info.model_hash}"
    if state.hash_ok is True:
        text += " matches model.json"
    elif state.hash_ok is False:
        text += f", MISMATCH: model.json is {state.expected_hash}"
    return text + (f" (CRC {'OK' if info.crc_ok else 'BAD'}), firmware {info.fw_version}, "
                   f"period {info.period_ms} ms")


def reference_line(state: MonitorState) -> str:
    if "REFERENCED" in state.flags:
        z = state.zero_seq()
        return ("corrections are the change since ZERO"
                + (f" (reference from sample #{z})" if z is not None else ""))
    return "corrections are absolute (no ZERO reference in force)"
