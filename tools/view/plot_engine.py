"""A small plotting engine on Pillow and numpy, for ``flight.png`` (``tools.view.flight_png``, the figure): panels
of lines against one shared time axis (:class:`Panel`, :class:`Line`), with grid, ticks, legends, notes, clipped
marks, dotted mode switches and dashed fault marks, drawn by :func:`render` in matplotlib's layout, sizes and font
(DejaVu Sans, read from matplotlib's package folder without importing matplotlib).

How it is drawn: every line, frame, tick and box on a canvas ``SS`` times the picture's size, which is then reduced
(each picture pixel the mean of SS x SS canvas pixels: the lines come out anti-aliased); the text after, on the
reduced picture (FreeType anti-aliases it, and it stays as sharp as matplotlib's).  Sizes are given in points at
matplotlib's 100 dpi, as they were in ``tools.view.plots``, and converted here (``PX``).  Coordinates are picture
pixels, floats, with pixel ``i`` covering ``[i, i + 1)``.  The same input gives the same bytes (no time stamp in the
PNG)."""

from __future__ import annotations

import importlib.util
import math
import os
import re
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from PIL import Image, ImageColor, ImageDraw, ImageFont

from tools.view import flight_scales
from tools.view.flight_scales import data_range, nice_ticks, tick_labels

DEG = 180.0 / math.pi
SIZE = 1100  # the picture, px (matplotlib's 11 x 11 in at 100 dpi)
SS = 2  # supersampling: shapes drawn at twice the size, then halved (Image.reduce: cheaper than a LANCZOS resize)
PX = 100.0 / 72.0  # pixels per point at 100 dpi

# The layout of the matplotlib figure (subplots_adjust(left=0.08, right=0.98, bottom=0.05, top=0.92, hspace=0.3)).
LEFT, RIGHT, TOP, BOTTOM = round(0.08 * SIZE), round(0.98 * SIZE), round(0.08 * SIZE), round(0.95 * SIZE)
HSPACE = 0.3  # the gap between panels, as a fraction of their mean height
RATIOS = (3, 2, 2)  # the panels' heights

# The marks' colours (the figure's lines take theirs: tools.view.flight_png)
C_GRID = "#e7e7e7"  # matplotlib's grid, #b0b0b0 at alpha 0.3 on white
C_MARK = "#4d4d4d"  # mode switches and rudder limits ("0.3")
C_FAULT = "#d55e00"  # a fault's start and end (sitl.damage), dashed, its name in the top panel
C_NOTE = "#666666"  # "not recorded" notes ("0.4")
C_LEGEND_EDGE = "#cccccc"
C_NOTE_EDGE = "#b3b3b3"

# Font sizes, points
PT_SUPTITLE, PT_TITLE, PT_LABEL, PT_TICK, PT_LEGEND, PT_NOTE, PT_MODE = 12, 10, 10, 10, 7.5, 8, 7
TICK_LEN = 3.5 * PX  # outward tick marks
TICK_PAD = 3.5 * PX  # between a tick mark and its label
LABEL_PAD = 4.0 * PX  # between the tick labels and the axis label
TITLE_PAD = 6.0 * PX  # between a panel's frame and its title
MODE_NAME_SLIP = 12.0  # px: how far right of its switch's line a mode's name may be pushed by the one before
# matplotlib's dash patterns, in multiples of the line width
DASHES = {"--": (3.7, 1.6), ":": (1.0, 1.65)}


# ---------------------------------------------------------------------------------------- fonts
def font_file() -> str | None:
    """DejaVu Sans, the font matplotlib draws with, from matplotlib's package folder (found, not imported)."""
    spec = importlib.util.find_spec("matplotlib")
    if spec is None or not spec.submodule_search_locations:
        return None
    path = os.path.join(spec.submodule_search_locations[0], "mpl-data", "fonts", "ttf", "DejaVuSans.ttf")
    return path if os.path.isfile(path) else None


@lru_cache(maxsize=None)
def _font(pt: float) -> ImageFont.FreeTypeFont:
    path = font_file()
    if path is not None:
        try:
            return ImageFont.truetype(path, pt * PX)
        except OSError:
            pass
    return ImageFont.load_default(pt * PX)  # Pillow's own font (FreeType), when matplotlib is not installed


# Subscripts: a label writes them "K_{e}" (as in matplotlib's mathtext), drawn smaller and lowered.  DejaVu has
# Unicode's subscript letters (ₑ, ₓ, ᵤ...), but at a legend's 7.5 pt they are too small to read.
SUB_SIZE = 0.7  # of the text's size
SUB_DROP = 0.2  # below the baseline, in ems of the text


def _runs(s: str) -> list[tuple[str, bool]]:
    """A label's pieces, (text, is a subscript): "K_{e} [-]" -> [("K", False), ("e", True), (" [-]", False)]."""
    parts = re.split(r"_\{([^}]*)\}", s)  # the subscripts at the odd places
    return [(p, i % 2 == 1) for i, p in enumerate(parts) if p]


def _mode_width(s: str) -> float:
    return text_width(s, PT_MODE)


def text_width(s: str, pt: float) -> float:
    """How wide a label is drawn, px."""
    return sum(_font(pt * SUB_SIZE if sub else pt).getlength(p) for p, sub in _runs(s))


def _draw_text(draw: ImageDraw.ImageDraw, x: float, y: float, s: str, pt: float, anchor: str, color) -> None:
    """Text at (x, y) by Pillow's ``anchor``; with subscripts, the vertical anchor is one of "a" or "t" (the font's
    ascender), "m" (middle), "s" (baseline), "b" or "d" (its descender): the font's, not the text's own box."""
    runs = _runs(s)
    font = _font(pt)
    if len(runs) <= 1 and not (runs and runs[0][1]):
        draw.text((x, y), s, font=font, fill=color, anchor=anchor)
        return
    ascent, descent = font.getmetrics()
    x -= {"l": 0.0, "m": 0.5, "r": 1.0}[anchor[0]] * text_width(s, pt)
    y += {"a": ascent, "t": ascent, "m": (ascent - descent) / 2, "s": 0, "b": -descent, "d": -descent}[anchor[1]]
    # (y is now the baseline)
    for part, sub in runs:
        f = _font(pt * SUB_SIZE) if sub else font
        draw.text((round(x), round(y + SUB_DROP * pt * PX if sub else y)), part, font=f, fill=color, anchor="ls")
        x += f.getlength(part)


# ---------------------------------------------------------------------------------------- axes
@dataclass
class _Axes:
    """A panel's frame (picture pixels: the frame's lines are rows ``top`` and ``bottom``, columns ``left`` and
    ``right``) and the data ranges it shows."""

    left: int
    top: int
    right: int
    bottom: int
    xlim: tuple[float, float]
    ylim: tuple[float, float]

    def x(self, v):
        return self.left + (np.asarray(v, float) - self.xlim[0]) / (self.xlim[1] - self.xlim[0]) * (
            self.right - self.left
        )

    def y(self, v):
        return self.bottom - (np.asarray(v, float) - self.ylim[0]) / (self.ylim[1] - self.ylim[0]) * (
            self.bottom - self.top
        )


def panel_frames() -> list[tuple[int, int, int, int]]:
    """(left, top, right, bottom) of each panel, from the top: matplotlib's grid of RATIOS with HSPACE."""
    total = BOTTOM - TOP
    mean = total / (len(RATIOS) + HSPACE * (len(RATIOS) - 1))
    frames, y = [], float(TOP)
    for r in RATIOS:
        h = mean * len(RATIOS) * r / sum(RATIOS)
        frames.append((LEFT, round(y), RIGHT, round(y + h)))
        y += h + HSPACE * mean
    return frames


# ---------------------------------------------------------------------------------------- what a panel shows
@dataclass
class Line:
    """A series drawn against the time ``t``: values (same length as t; NaN or inf: a gap), colour, width in points,
    style ("-", "--" dashed, ":" dotted), held until the next sample (``steps``, matplotlib's steps-post) or joined,
    its legend label, and its z order (higher: drawn later, on top).  ``y=None``: a legend entry only."""

    y: np.ndarray | None
    color: str
    lw: float = 1.0
    style: str = "-"
    steps: bool = False
    label: str | None = None
    z: int = 2
    wrap: float | None = None  # a wrapped angle: not joined where it jumps by more than this (180 deg)


@dataclass
class Panel:
    title: str
    ylabel: str
    lines: list[Line] = field(default_factory=list)  # drawn by z order; legend in this order
    hlines: list[float] = field(default_factory=list)  # dotted horizontal lines (the rudder's limits), data units
    legend_cols: int = 1
    missing: list[str] = field(default_factory=list)  # the series this flight's files do not have
    note: list[str] = field(default_factory=list)  # lines of text in a box at the bottom right
    ylim: tuple[float, float] | None = None  # the y range; None: the data's
    clipped: list[tuple[np.ndarray, bool, str]] = field(default_factory=list)  # (times, above, colour): marks

    @property
    def has_data(self) -> bool:
        return any(ln.y is not None for ln in self.lines)


# ---------------------------------------------------------------------------------------- the canvas
class _Canvas:
    """The picture being drawn: shapes at SS x the size (``self.big``), text queued and drawn by ``finish`` on the
    reduced picture, over the shapes."""

    def __init__(self) -> None:
        self.big = Image.new("RGB", (SIZE * SS, SIZE * SS), "white")
        self.draw = ImageDraw.Draw(self.big)
        self.texts: list[tuple] = []

    # Shapes.  A canvas pixel j covers picture coordinates [j / SS, (j + 1) / SS).
    def rule(self, horizontal: bool, at: float, a: float, b: float, color: str, dotted_lw: float = 0.0) -> None:
        """A crisp 1 px line covering [a, b) along picture row ``at`` (horizontal) or column ``at`` (vertical):
        grid, frames, ticks; dotted if ``dotted_lw`` (matplotlib's ":" for a line that wide, in points)."""
        if dotted_lw:
            on, off = (d * dotted_lw * PX for d in DASHES[":"])
            starts = np.arange(a, b, on + off)
            spans = zip(starts, np.minimum(starts + on, b))
        else:
            spans = [(a, b)]
        across = math.floor(at) * SS  # the whole picture pixel: SS canvas pixels
        for s, e in spans:
            s, e = round(s * SS), round(e * SS) - 1  # along: to the canvas pixel (dots of sub-pixel length)
            if e < s:
                continue
            box = (s, across, e, across + SS - 1) if horizontal else (across, s, across + SS - 1, e)
            self.draw.rectangle(box, fill=color)

    def polyline(self, x: np.ndarray, y: np.ndarray, color: str, lw: float, style: str = "-") -> None:
        """Picture coordinates joined by a line ``lw`` points wide, solid or with matplotlib's dashes."""
        width = max(1, round(lw * PX * SS))
        # a canvas pixel j is drawn around coordinate j: picture coordinate c is at canvas c * SS - 0.5
        cx, cy = x * SS - 0.5, y * SS - 0.5
        if style == "-":
            pieces = [(cx, cy)]
        else:
            on, off = (d * lw * PX * SS for d in DASHES[style])
            pieces = _dashes(cx, cy, on, off)
        for px, py in pieces:
            if len(px) >= 2:
                self.draw.line(np.column_stack((px, py)).ravel().tolist(), fill=color, width=width)

    def triangle(self, x: float, tip: float, base: float, color: str) -> None:
        """A filled triangle, its tip at (x, tip), its base 8 px wide on row ``base`` (picture coordinates)."""
        pts = [(x, tip), (x - 4, base), (x + 4, base)]
        self.draw.polygon([(px * SS, py * SS) for px, py in pts], fill=color)

    def box(self, x0: float, y0: float, x1: float, y1: float, edge: str | None, alpha: float = 0.9) -> None:
        """A white box, ``alpha`` opaque over what is drawn (a legend's, a note's), with a rounded 1 px edge."""
        b = tuple(round(v * SS) for v in (x0, y0, x1, y1))
        region = self.big.crop(b)
        self.big.paste(Image.blend(region, Image.new("RGB", region.size, "white"), alpha), b[:2])
        if edge:
            self.draw.rounded_rectangle(b, radius=2 * SS, outline=edge, width=SS)

    # Text, drawn after the reduction: ``anchor`` is Pillow's (e.g. "rm": right, middle); a rotated text (read
    # upwards) is placed by its right edge and middle.
    def text(self, xy, s: str, pt: float, anchor: str = "la", color: str = "#000000", rotate: bool = False) -> None:
        self.texts.append((xy, s, pt, anchor, color, rotate))

    def finish(self) -> Image.Image:
        img = self.big.reduce(SS) if SS > 1 else self.big
        draw = ImageDraw.Draw(img)
        for (x, y), s, pt, anchor, color, rotate in self.texts:
            x, y = round(x), round(y)  # whole pixels: each glyph drawn the same wherever it is (no sub-pixel shift)
            font = _font(pt)
            if not rotate:
                _draw_text(draw, x, y, s, pt, anchor, color)
                continue
            # A quarter turn (an axis label): drawn on a mask, turned, pasted with its right edge at x, centred on y
            x0, y0, x1, y1 = font.getbbox(s, anchor="ls")
            mask = Image.new("L", (x1 - x0, y1 - y0))
            ImageDraw.Draw(mask).text((-x0, -y0), s, font=font, fill=255, anchor="ls")
            mask = mask.transpose(Image.Transpose.ROTATE_90)
            img.paste(ImageColor.getrgb(color), (round(x - mask.width), round(y - mask.height / 2)), mask)
        return img


def _dashes(x: np.ndarray, y: np.ndarray, on: float, off: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """The pieces of a polyline a dash pattern draws: ``on`` long, then ``off`` not, along its length."""
    seg = np.hypot(np.diff(x), np.diff(y))
    keep = np.concatenate(([True], seg > 0))  # repeated points would stop np.interp's positions increasing
    x, y = x[keep], y[keep]
    s = np.concatenate(([0.0], np.cumsum(seg[seg > 0])))
    starts = np.arange(0.0, s[-1], on + off)
    ends = np.minimum(starts + on, s[-1])
    # the polyline's vertices and the dashes' ends, in order along it (np.sort, not np.union1d: that imports numpy.ma)
    at = np.sort(np.concatenate((s, starts, ends)))
    px, py = np.interp(at, s, x), np.interp(at, s, y)
    i0 = np.searchsorted(at, starts)
    i1 = np.searchsorted(at, ends, side="right")
    return [(px[i:j], py[i:j]) for i, j in zip(i0, i1)]


def _envelope(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The points to draw of a long series: in each canvas pixel column, its first and last point, its lowest and
    highest value.  The line drawn through them covers the same pixels as through all of them (a spike stays
    visible, however short), with at most four points a column.  Unchanged when the points are few or the x's are
    not in order."""
    col = np.floor(x * SS).astype(np.int64)
    if len(x) < 4 * (col[-1] - col[0] + 1) or np.any(col[1:] < col[:-1]):
        return x, y
    first = np.flatnonzero(np.concatenate(([True], col[1:] != col[:-1])))
    last = np.concatenate((first[1:], [len(x)])) - 1
    lo, hi = np.minimum.reduceat(y, first), np.maximum.reduceat(y, first)
    mid = (x[first] + x[last]) / 2  # the low and high points drawn at the column's middle (a vertical stroke)
    ex = np.column_stack((x[first], mid, mid, x[last])).ravel()
    ey = np.column_stack((y[first], lo, hi, y[last])).ravel()
    return ex, ey


def _finite_runs(t: np.ndarray, y: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The stretches of (t, y) with finite values: a NaN or an infinity is a gap in the line (as in matplotlib)."""
    ok = np.isfinite(t) & np.isfinite(y)
    if ok.all():
        return [(t, y)]
    edges = np.flatnonzero(np.diff(np.concatenate(([0], ok.astype(np.int8), [0]))))
    return [(t[a:b], y[a:b]) for a, b in zip(edges[::2], edges[1::2])]


def _steps_post(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each value held until the next sample: the corners of the staircase (only where the value changes)."""
    k = np.flatnonzero(y[1:] != y[:-1]) + 1
    xs = np.concatenate(([t[0]], np.repeat(t[k], 2), [t[-1]]))
    ys = np.concatenate(([y[0]], np.column_stack((y[k - 1], y[k])).ravel(), [y[-1]]))
    return xs, ys


# ---------------------------------------------------------------------------------------- drawing
def _legend(c: _Canvas, ax: _Axes, entries: list[Line], cols: int) -> None:
    """A legend in the panel's upper right corner: a sample of each line and its label (matplotlib's sizes)."""
    font = _font(PT_LEGEND)
    em = PT_LEGEND * PX
    pad, gap, handle, hpad, colgap, inset = 0.4 * em, 0.5 * em, 2.0 * em, 0.8 * em, 2.0 * em, 0.5 * em
    ascent, descent = font.getmetrics()
    row_h = ascent + descent
    rows = math.ceil(len(entries) / cols)
    columns = [entries[i * rows : (i + 1) * rows] for i in range(cols)]  # filled down, then across
    widths = [max(text_width(e.label, PT_LEGEND) for e in col) for col in columns if col]
    width = 2 * pad + sum(handle + hpad + w for w in widths) + colgap * (len(widths) - 1)
    height = 2 * pad + rows * row_h + (rows - 1) * gap
    x1, y0 = ax.right - inset, ax.top + inset
    x0, y1 = x1 - width, y0 + height
    c.box(x0, y0, x1, y1, C_LEGEND_EDGE)
    x = x0 + pad
    for col, w in zip(columns, widths):
        for i, e in enumerate(col):
            ym = y0 + pad + i * (row_h + gap) + row_h / 2
            c.polyline(np.array([x, x + handle]), np.array([ym, ym]), e.color, e.lw, e.style)
            c.text((x + handle + hpad, ym), e.label, PT_LEGEND, anchor="lm")
        x += handle + hpad + w + colgap


def _note_box(c: _Canvas, ax: _Axes, lines: list[str]) -> None:
    """Text lines in a box, right and bottom aligned at 99 % and 2 % of the panel (the tracking panel's numbers)."""
    font = _font(PT_NOTE)
    ascent, descent = font.getmetrics()
    step = 1.2 * PT_NOTE * PX  # matplotlib's line spacing
    pad = 0.2 * PT_NOTE * PX + 2
    width = max(font.getlength(s) for s in lines)
    x1 = ax.left + 0.99 * (ax.right - ax.left)
    y1 = ax.bottom - 0.02 * (ax.bottom - ax.top)
    top = y1 - (len(lines) - 1) * step - ascent - descent
    c.box(x1 - width - 2 * pad, top - pad, x1, y1 + pad - 2, C_NOTE_EDGE)
    for i, s in enumerate(lines):
        c.text((x1 - pad, top + i * step), s, PT_NOTE, anchor="ra")


def _draw_panel(
    c: _Canvas, ax: _Axes, panel: Panel, t: np.ndarray, xticks: np.ndarray, modes: list, last: bool, faults=()
) -> None:
    # grid at the ticks, under everything
    yticks = nice_ticks(*ax.ylim, _bins(ax.bottom - ax.top, 2)) if panel.has_data else np.empty(0)
    for v in xticks:
        c.rule(False, ax.x(v), ax.top, ax.bottom, C_GRID)
    for v in yticks:
        c.rule(True, ax.y(v), ax.left, ax.right, C_GRID)
    # the series, in z order (a stable sort: then in the order given), each finite stretch on its own
    columns = ax.x(t)
    for ln in sorted((ln for ln in panel.lines if ln.y is not None), key=lambda ln: ln.z):
        for x, v in (r for run in _finite_runs(columns, ln.y) for r in flight_scales.wrap_runs(*run, ln.wrap)):
            if len(x) < 2:
                continue
            if ln.steps:
                x, v = _steps_post(x, v)
            x, y = _envelope(x, ax.y(np.clip(v, *(panel.ylim or (-1e300, 1e300)))))
            c.polyline(x, y, ln.color, ln.lw, ln.style)
    for times, above, color in panel.clipped:  # a clipped value: a triangle at the edge, pointing out
        tip = ax.top + 1 if above else ax.bottom
        for col in np.unique(np.round(ax.x(times))):
            c.triangle(float(col), tip, tip + (8 if above else -8), color)
    for v in panel.hlines:
        c.rule(True, ax.y(v), ax.left, ax.right, C_MARK, dotted_lw=0.8)
    for ts, _name in modes:  # the mode switches, under the legend and the notes
        c.rule(False, ax.x(ts), ax.top, ax.bottom, C_MARK, dotted_lw=0.8)
    for ts, _name, *color in faults:  # a fault's start or end (a parameter change), where it lies on the time axis
        if ax.xlim[0] <= ts <= ax.xlim[1]:
            c.rule(False, ax.x(ts), ax.top, ax.bottom, color[0] if color else C_FAULT, dotted_lw=1.6)
    # frame and ticks (outward); tick labels at the left, and at the bottom of the last panel only (shared time axis)
    for horizontal, at, a, b in (
        (True, ax.top, ax.left, ax.right + 1),
        (True, ax.bottom, ax.left, ax.right + 1),
        (False, ax.left, ax.top, ax.bottom + 1),
        (False, ax.right, ax.top, ax.bottom + 1),
    ):
        c.rule(horizontal, at, a, b, "#000000")
    for v in xticks:
        c.rule(False, ax.x(v), ax.bottom + 1, ax.bottom + 1 + TICK_LEN, "#000000")
    labels, multiplier = tick_labels(yticks)
    for v, s in zip(yticks, labels):
        y = math.floor(ax.y(v)) + 0.5
        c.rule(True, y, ax.left - TICK_LEN, ax.left, "#000000")
        c.text((ax.left - TICK_LEN - TICK_PAD, y), s, PT_TICK, anchor="rm")
    if multiplier:
        c.text((ax.left, ax.top - 3), multiplier, PT_TICK, anchor="ld")
    widest = max((_font(PT_TICK).getlength(s) for s in labels), default=0.0)
    c.text(  # left of the tick labels, but inside the picture
        (max(ax.left - TICK_LEN - TICK_PAD - widest - LABEL_PAD, 1.3 * PT_LABEL * PX), (ax.top + ax.bottom) / 2),
        panel.ylabel,
        PT_LABEL,
        rotate=True,
    )
    if last:
        xlabels, xmultiplier = tick_labels(xticks)
        for v, s in zip(xticks, xlabels):
            c.text((math.floor(ax.x(v)) + 0.5, ax.bottom + TICK_LEN + TICK_PAD), s, PT_TICK, anchor="mt")
        if xmultiplier:  # below the labels' right end, as matplotlib writes an axis's offset
            c.text((ax.right, ax.bottom + TICK_LEN + TICK_PAD + 1.2 * PT_TICK * PX), xmultiplier, PT_TICK, anchor="rt")
        c.text(
            ((ax.left + ax.right) / 2, ax.bottom + TICK_LEN + TICK_PAD + 1.2 * PT_TICK * PX + LABEL_PAD),
            "t [s]",
            PT_LABEL,
            anchor="mt",
        )
    # what is laid over the lines: the legend, the note, the missing series
    entries = [ln for ln in panel.lines if ln.label]
    if entries:
        _legend(c, ax, entries, panel.legend_cols)
    if panel.note:
        _note_box(c, ax, panel.note)
    if panel.missing:
        text = "not recorded by this transport: " + ", ".join(panel.missing)
        ym = (ax.top + ax.bottom) / 2
        if panel.has_data:  # at the right, on a veil over the lines
            x1 = ax.left + 0.99 * (ax.right - ax.left)
            half = 0.6 * PT_NOTE * PX
            c.box(x1 - text_width(text, PT_NOTE) - 2, ym - half, x1 + 2, ym + half, edge=None, alpha=0.8)
            c.text((x1, ym), text, PT_NOTE, anchor="rm", color=C_NOTE)
        else:
            c.text(((ax.left + ax.right) / 2, ym), text, PT_NOTE, anchor="mm", color=C_NOTE)


def _bins(length_px: float, per_label: float) -> int:
    """How many intervals between ticks an axis gets: one per ``per_label`` tick-label heights of its length (2 for
    a vertical axis, 3 for a horizontal one), 1 to 9 (matplotlib's rule)."""
    return int(min(9, max(1, (length_px / PX) // (per_label * PT_TICK))))


def render(
    t: np.ndarray, panels: list[Panel], modes: list[tuple[float, str]], title: str, faults: list[tuple[float, str]] = ()
) -> Image.Image:
    """The picture: ``panels`` (from the top, len(RATIOS) of them) against the time ``t``, a dotted line at each
    mode switch ((time, name)) in every panel with its name above the top panel, an orange one at each fault's
    start and end ((time, text)) with its text in the top panel, the title above all."""
    c = _Canvas()
    frames = panel_frames()
    xlim = data_range([t]) or (0.0, 1.0)
    xticks = nice_ticks(*xlim, _bins(frames[0][2] - frames[0][0], 3))  # one time axis for all the panels
    for i, (panel, frame) in enumerate(zip(panels, frames)):
        values = [ln.y for ln in panel.lines if ln.y is not None] + [np.asarray(panel.hlines, float)]
        ax = _Axes(*frame, xlim, panel.ylim or data_range(values) or (0.0, 1.0))
        _draw_panel(c, ax, panel, t, xticks, modes, last=i == len(panels) - 1, faults=faults)
        if i == 0:  # the faults' texts in the top panel, reading upwards, left of their lines, merged if together
            shown = [(float(ax.x(ts)), s, (c0 or [C_FAULT])[0]) for ts, s, *c0 in faults if xlim[0] <= ts <= xlim[1]]
            for group in flight_scales.label_groups([m[0] for m in shown], 1.3 * PT_MODE * PX):
                marks = [shown[k] for k in group]
                text = flight_scales.merged_label([m[1] for m in marks], _mode_width, ax.bottom - ax.top - 10)
                color = marks[0][2] if len({m[2] for m in marks}) == 1 else C_FAULT
                c.text((marks[0][0] - 1, (ax.top + ax.bottom) / 2), text, PT_MODE, color=color, rotate=True)
        title_y = ax.top - TITLE_PAD
        if i == 0 and modes:
            # The names, each after the previous one if they would overlap; one that would land more than
            # MODE_NAME_SLIP px from its line, or past the picture's edge, is left out (its line stays): a mode
            # that flaps every few steps would otherwise write its names far from their switches.
            end = -math.inf
            for ts, name in modes:
                x = max(float(ax.x(ts)), end + 4)
                width = text_width(name, PT_MODE)
                if x - float(ax.x(ts)) > MODE_NAME_SLIP or x + width > SIZE - 2:
                    continue
                c.text((x, ax.top - 0.01 * (ax.bottom - ax.top)), name, PT_MODE, anchor="ld")
                end = x + width
            title_y -= 1.6 * PT_MODE * PX  # the title above the names
        c.text(((ax.left + ax.right) / 2, title_y), panel.title, PT_TITLE, anchor="md")
    c.text((SIZE / 2, 0.02 * SIZE), title, PT_SUPTITLE, anchor="mt")
    return c.finish()
