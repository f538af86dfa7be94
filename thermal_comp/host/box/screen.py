"""The monitor's full-screen terminal view, on curses (the standard library's terminal library).

Why curses and not escape sequences written by hand: the old in-place redraw moved the cursor
up by the number of lines it had printed, but a line longer than the terminal wraps into two,
so at 80 columns every frame left lines behind and the screen filled with garbage; a resize did
the same. Here every frame is laid out for the terminal's size as it is now (``layout``: each
line clipped to the width, sections dropped by priority when the height is short) and curses
repaints only what changed. A resize (SIGWINCH, ``KEY_RESIZE``) is picked up at the next frame.

``layout`` is pure (lines in, lines out) so it is tested without a terminal; ``Screen`` is the
thin curses shell around it. Colour marks come in the lines as the ANSI codes ``render`` uses
(grey, bold red, reset) and become curses attributes.
"""

from __future__ import annotations

import curses
import locale
import os
import re
from collections.abc import Iterator, Sequence

GREY, RED, RESET = "\x1b[90m", "\x1b[1;31m", "\x1b[0m"
_MARK = re.compile(r"(\x1b\[90m|\x1b\[1;31m|\x1b\[0m)")
# what a terminal without UTF-8 gets instead (every replacement keeps the line's meaning)
_ASCII = str.maketrans({"µ": "u", "°": "deg ", "−": "-", "─": "-", "…": ">", "±": "+-"})


def visible(line: str) -> str:
    """The line without its colour marks."""
    return _MARK.sub("", line)


def clip(line: str, width: int, ellipsis: str = "…") -> str:
    """The line cut to ``width`` visible characters (colour marks kept, not counted); a cut line
    ends in ``ellipsis``."""
    if width <= 0:
        return ""
    if len(visible(line)) <= width:
        return line
    out, n = [], 0
    for part in _MARK.split(line):
        if _MARK.fullmatch(part):
            out.append(part)
            continue
        room = width - 1 - n
        if room <= 0:
            continue
        out.append(part[:room])
        n += min(len(part), room)
    return "".join(out) + ellipsis + RESET


def layout(main: Sequence[str], history: Sequence[str], events: Sequence[str], height: int,
           width: int, ellipsis: str = "…") -> list[str]:
    """The frame for a ``height`` x ``width`` terminal: ``main`` first (the live state), then
    the fault history (newest first), then the latest events; every line clipped to the width
    (one column spare: curses cannot write the bottom-right cell). When the height is short the
    main block keeps its head, the history keeps at least its newest entries, events go first."""
    if height <= 0 or width <= 1:
        return []
    w = width - 1
    rows = list(main[:height])
    room = height - len(rows)
    hist = ["─── fault history (newest first) " + "─" * max(0, w - 33)] + (
        list(history) if history else ["  none since the monitor started"])
    ev = ["─── events " + "─" * max(0, w - 11)] + [f"  {e}" for e in events]
    # the history's title and newest entries first, then the latest events (title and three),
    # then the rest of the history, then more events
    want_ev = min(len(ev), 4) if events else 0
    take_hist = max(min(len(hist), 3, room), min(len(hist), room - want_ev)) if room >= 2 else 0
    if take_hist == 1:
        take_hist = 0  # a title alone says nothing
    rows += hist[:take_hist]
    room = height - len(rows)
    if room >= 2 and events:
        rows += [ev[0]] + ev[1:][-(room - 1):]
    return [clip(r, w, ellipsis) for r in rows]


def segments(line: str) -> Iterator[tuple[str, str]]:
    """(text, style) pieces of a line: style "" plain, "grey" or "red"."""
    style = ""
    for part in _MARK.split(line):
        if part == GREY:
            style = "grey"
        elif part == RED:
            style = "red"
        elif part == RESET:
            style = ""
        elif part:
            yield part, style


class Screen:
    """curses around ``layout``: ``start``, ``draw`` each frame, ``key`` (non-blocking: "quit"
    for q, "resize" after a resize), ``stop`` (always: it gives the terminal back)."""

    def __init__(self) -> None:
        self._win: curses.window | None = None
        self._attr = {"": 0, "grey": 0, "red": 0}
        self.utf8 = True

    def start(self) -> None:
        locale.setlocale(locale.LC_ALL, "")
        self.utf8 = locale.getpreferredencoding(False).lower().replace("-", "") == "utf8"
        # the size from the terminal, always: LINES/COLUMNS in the environment (a shell may
        # export them) override it in curses, and a resize would go unseen
        for name in ("LINES", "COLUMNS"):
            os.environ.pop(name, None)
        win = curses.initscr()
        self._win = win
        try:
            curses.noecho()
            curses.cbreak()
            win.keypad(True)
            win.nodelay(True)
            try:
                curses.curs_set(0)
            except curses.error:
                pass  # a terminal that cannot hide the cursor
            self._attr = {"": curses.A_NORMAL, "grey": curses.A_DIM,
                          "red": curses.A_BOLD | curses.A_REVERSE}
            if curses.has_colors():
                curses.start_color()
                curses.use_default_colors()
                curses.init_pair(1, curses.COLOR_RED, -1)
                self._attr["red"] = curses.A_BOLD | curses.color_pair(1)
                if curses.COLORS >= 16:
                    curses.init_pair(2, 8, -1)  # bright black: grey
                    self._attr["grey"] = curses.color_pair(2)
        except BaseException:
            self.stop()
            raise

    def size(self) -> tuple[int, int]:
        assert self._win is not None
        return self._win.getmaxyx()

    def draw(self, main: Sequence[str], history: Sequence[str], events: Sequence[str]) -> None:
        win = self._win
        if win is None:
            return
        height, width = win.getmaxyx()
        ellipsis = "…" if self.utf8 else ">"
        win.erase()
        for y, line in enumerate(layout(main, history, events, height, width, ellipsis)):
            x = 0
            for text, style in segments(line):
                shown = text if self.utf8 else text.translate(_ASCII)
                try:
                    win.addnstr(y, x, shown, max(0, width - 1 - x), self._attr[style])
                except curses.error:
                    pass  # the terminal shrank under us: the next frame fits again
                x += len(shown)
        win.noutrefresh()
        curses.doupdate()

    def key(self) -> str | None:
        win = self._win
        if win is None:
            return None
        try:
            ch = win.getch()
        except curses.error:
            return None
        if ch == curses.KEY_RESIZE:
            curses.update_lines_cols()
            return "resize"
        if ch in (ord("q"), ord("Q")):
            return "quit"
        return None

    def stop(self) -> None:
        if self._win is None:
            return
        try:
            self._win.keypad(False)
            curses.nocbreak()
            curses.echo()
        except curses.error:
            pass
        curses.endwin()
        self._win = None
