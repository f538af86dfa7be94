"""The report's PNGs: each figure drawn once on an Agg canvas, checked on that drawing for
legends and labels cut off at the image's edge (``clipped_artists``), and written from the same
pixels. Apart from the figures (host.analysis.plots) because saving is one job for all of them.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
from matplotlib import image  # noqa: E402
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

PNG_DPI = 100
CLIP_TOLERANCE_PX = 1.0


def _drawn(fig: Figure, dpi: float) -> FigureCanvasAgg:
    """``fig`` drawn (its layout engine run) on an Agg canvas at ``dpi``, as savefig draws it."""
    fig.set_dpi(dpi)
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return canvas


def clipped_artists(fig: Figure, dpi: float = PNG_DPI,
                    canvas: FigureCanvasAgg | None = None) -> list[str]:
    """What of ``fig`` would lie (partly) outside the image saved at ``dpi``: every legend,
    title, axis label, tick-label row and text, each named; [] when everything is inside.
    ``canvas``: the figure already drawn at that dpi (else it is drawn here)."""
    canvas = canvas or _drawn(fig, dpi)
    renderer = canvas.get_renderer()
    width, height = fig.bbox.width, fig.bbox.height
    tol = CLIP_TOLERANCE_PX
    named: list[tuple[str, object]] = [(f"figure legend {k}", leg)
                                       for k, leg in enumerate(fig.legends)]
    named += [(f"figure text {t.get_text()!r}", t) for t in fig.texts]
    for k, ax in enumerate(fig.axes):
        where = f"axes {k} ({ax.get_title() or ax.get_ylabel() or ax.get_label()})"
        if ax.get_legend() is not None:
            named.append((f"{where}: legend", ax.get_legend()))
        named += [(f"{where}: {what}", t) for what, t in (
            ("title", ax.title), ("left title", ax._left_title),
            ("right title", ax._right_title), ("x label", ax.xaxis.label),
            ("y label", ax.yaxis.label))]
        named += [(f"{where}: text {t.get_text()!r}", t) for t in ax.texts]
        named += [(f"{where}: {name} tick labels", axis)
                  for name, axis in (("x", ax.xaxis), ("y", ax.yaxis))]
    out = []
    for name, artist in named:
        if not artist.get_visible() or (hasattr(artist, "get_text")
                                        and not artist.get_text().strip()):
            continue
        box = (artist.get_tightbbox(renderer) if hasattr(artist, "get_ticklabels")
               else artist.get_window_extent(renderer))
        if box is None or box.width == 0 and box.height == 0:
            continue
        if box.x0 < -tol or box.y0 < -tol or box.x1 > width + tol or box.y1 > height + tol:
            out.append(f"{name} at x {box.x0:.0f}..{box.x1:.0f}, y {box.y0:.0f}..{box.y1:.0f} "
                       f"px outside the {width:.0f}×{height:.0f} px image")
    return out


def save_png(fig: Figure, path: str | Path, dpi: float = PNG_DPI) -> list[str]:
    """Write ``fig`` as a PNG at ``path`` (atomically) and return clipped_artists: what a
    reader would find cut off at its edge."""
    path = Path(path)
    canvas = _drawn(fig, dpi)  # drawn once: checked, then written from the same pixels
    clipped = clipped_artists(fig, dpi, canvas)
    tmp = path.with_name(path.name + ".tmp")
    image.imsave(tmp, np.asarray(canvas.buffer_rgba()), format="png", dpi=dpi)
    tmp.replace(path)
    return clipped
