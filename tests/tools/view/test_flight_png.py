"""flight.png drawn with Pillow (``tools.view.flight_png`` on ``tools.view.plot_engine``), checked on the picture read
back, against what is known of the flight drawn, not against the renderer's own numbers: the panels' frames, grid
lines and tick labels are found in the pixels (a label is read by matching it with the digits drawn in the same
font), and a series of known value must lie where the grid lines and their labels put that value; each series' colour
is in its panel only when the flight has the series; a missing one is said; a mode switch is marked at its time; NaN
and infinite values leave gaps, not a crash; no series, no picture. In this process, no children: each picture takes
a few tens of milliseconds."""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image, ImageColor, ImageDraw, ImageFont

from tools.view import flight_png, plot_engine
from tools.view.flight_picture import draw_flight_png
from tools.view.flight_png import flight_image
from tools.view.flight_scales import nice_ticks

N = 3001  # a 30 s flight at 100 Hz
DEG = math.pi / 180.0
T = np.arange(N) / 100.0
SQUARE = np.where((T // 5) % 2 == 0, 1.0, -1.0)  # +1 for 5 s, -1 for 5 s, ...
GRID = ImageColor.getrgb(plot_engine.C_GRID)


def _series(**over) -> dict:
    """A flight whose every series is piecewise constant and at its own level: command +-10 deg, open-loop model
    +-8, closed-loop model +-6, roll a constant 4 deg, rudder +-3 deg, gains 0.1, -0.05, 0.02.  ``key=None``:
    without that series."""
    s = {
        "t": T,
        "um": 10 * DEG * SQUARE,
        "ym_ol": 8 * DEG * SQUARE,
        "ym": 6 * DEG * SQUARE,
        "phi": np.full(N, 4 * DEG),
        "u": 3 * DEG * SQUARE,
        "ke": np.full(N, 0.1),
        "kx": np.full(N, -0.05),
        "ku": np.full(N, 0.02),
        "mode": np.full(N, 101.0),
    }
    s.update(over)
    return {k: v for k, v in s.items() if v is not None}


def _draw(series: dict, lv: float = 20.0) -> np.ndarray:
    img = flight_image(
        series, name="clsac", lv=lv, metrics={"ise_ref": 0.01}, u_limit_rad=30 * DEG, title="Flight test: clsac"
    )
    assert img.size == (1100, 1100) and img.mode == "RGB"
    return np.asarray(img).astype(int)


# ---------------------------------------------------------------------------------------- reading the picture
def _frames(px: np.ndarray) -> list[tuple[int, int, int, int]]:
    """(left, top, right, bottom) of each panel: its frame's rows are the only ones with 900 black pixels and more
    (the command's line is dashed)."""
    black = (px == 0).all(axis=2)
    rows = np.flatnonzero(black.sum(axis=1) >= 900)
    assert len(rows) == 6, rows
    cols = np.flatnonzero(black[rows[0]])
    return [(int(cols[0]), int(rows[i]), int(cols[-1]), int(rows[i + 1])) for i in (0, 2, 4)]


def _coverage(px: np.ndarray, color: str) -> np.ndarray:
    """How much of each pixel a line of ``color`` covers, 0..1, for a line drawn on white and anti-aliased: the
    pixel is white mixed with that colour; 0 for a pixel of another colour (not such a mix)."""
    c = 255 - np.array(ImageColor.getrgb(color), float)
    ink = 255 - px
    k = np.clip((ink * c).sum(axis=-1) / (c @ c), 0.0, 1.0)
    other = np.linalg.norm(ink - k[..., None] * c, axis=-1) > 25
    return np.where(other, 0.0, k)


def _solid(px: np.ndarray, color: str, run: int = 8) -> np.ndarray:
    """Pixels exactly of ``color`` starting a run of ``run`` along a row: a line's flat stretch, not anti-aliased
    text."""
    exact = (px == ImageColor.getrgb(color)).all(axis=-1)
    starts = exact.copy()
    for k in range(1, run):
        starts[:, :-k] &= exact[:, k:]
    return starts


@pytest.fixture(scope="module")
def digits():
    """The labels a tick may have in these flights, drawn in DejaVu at the tick labels' size as black masks: right
    aligned (a y axis's labels) and centred (the time axis's), as the glyphs' places in a label depend on it."""
    font = ImageFont.truetype(plot_engine.font_file(), plot_engine.PT_TICK * plot_engine.PX)
    masks = {"rm": {}, "mt": {}}
    for v in np.arange(-40, 40.5, 0.5):
        for s in {f"{v:.1f}", f"{v:.0f}" if v == int(v) else f"{v:.1f}"}:
            s = s.replace("-", "\u2212")
            for anchor, masked in masks.items():
                img = Image.new("L", (120, 40), 255)
                ImageDraw.Draw(img).text((60, 20), s, font=font, fill=0, anchor=anchor)
                masked[s] = _crop(np.asarray(img) < 128)
    return masks


def _crop(mask: np.ndarray) -> np.ndarray:
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    return mask[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1] if len(rows) else mask[:0, :0]


def _read(px: np.ndarray, rows: slice, cols: slice, digits: dict, alone: bool = False) -> float:
    """The number written in a region (black text on white): the label whose drawing matches it best.  ``alone``:
    without the columns that have text above or below the region too (a y axis's label, read upwards, beside its
    tick labels)."""
    dark = px[rows, cols].mean(axis=-1) < 128
    if alone:
        around = px[rows.start - 20 : rows.stop + 20, cols].mean(axis=-1) < 128
        dark[:, around.sum(axis=0) > dark.sum(axis=0)] = False
    seen = _crop(dark)
    best, score = None, 0.0
    for s, m in digits.items():
        if abs(m.shape[0] - seen.shape[0]) > 1 or abs(m.shape[1] - seen.shape[1]) > 1:
            continue
        h, w = max(m.shape[0], seen.shape[0]), max(m.shape[1], seen.shape[1])
        a, b = np.zeros((h, w), bool), np.zeros((h, w), bool)
        a[: m.shape[0], : m.shape[1]], b[: seen.shape[0], : seen.shape[1]] = m, seen
        iou = (a & b).sum() / max((a | b).sum(), 1)
        if iou > score:
            best, score = s, iou
    assert best is not None and score > 0.9, (best, score)
    return float(best.replace("\u2212", "-"))


def _y_grid(px: np.ndarray, frame, digits) -> list[tuple[int, float]]:
    """(row, value) of a panel's horizontal grid lines: rows a quarter of whose pixels are the grid's colour, each
    value read from the tick label beside it."""
    left, top, right, bottom = frame
    inside = px[top + 1 : bottom, left + 1 : right]
    rows = np.flatnonzero((inside == GRID).all(axis=-1).sum(axis=1) >= 0.25 * (right - left)) + top + 1
    assert len(rows) >= 2, rows
    return [
        (int(r), _read(px, slice(r - 10, r + 11), slice(left - 60, left - 6), digits["rm"], alone=True)) for r in rows
    ]


def _x_grid(px: np.ndarray, frames, digits) -> list[tuple[int, float]]:
    """(column, time) of the vertical grid lines, each time read from the label under the bottom panel."""
    left, top, right, bottom = frames[2]
    inside = px[top + 1 : bottom, left + 1 : right]
    cols = np.flatnonzero((inside == GRID).all(axis=-1).sum(axis=0) >= 0.5 * (bottom - top)) + left + 1
    assert len(cols) >= 2, cols
    return [(int(c), _read(px, slice(bottom + 6, bottom + 26), slice(c - 18, c + 19), digits["mt"])) for c in cols]


def _at(grid: list[tuple[int, float]], value: float) -> float:
    """Where ``value`` is, interpolating linearly between the two grid lines around it (or the nearest two)."""
    (p0, v0), (p1, v1) = sorted(grid, key=lambda g: (abs(g[1] - value), g[1]))[:2]
    return p0 + (value - v0) / (v1 - v0) * (p1 - p0)


# ---------------------------------------------------------------------------------------- the picture
def test_the_picture_is_a_1100_px_square_rgb_png_drawn_the_same_every_time(tmp_path):
    from tools.view.flight_png import save_flight_png

    kw = dict(name="clsac", lv=20.0, metrics={"ise_ref": 0.01}, u_limit_rad=30 * DEG, title="t")
    a = save_flight_png(tmp_path / "a.png", _series(), **kw)
    b = save_flight_png(tmp_path / "b.png", _series(), **kw)
    with Image.open(a) as img:
        assert img.format == "PNG" and img.size == (1100, 1100) and img.mode == "RGB"
    assert a.read_bytes() == b.read_bytes()


@pytest.mark.parametrize(
    "roll_deg, lv, color",
    [(np.full(N, 4.0), 20.0, flight_png.C_CLSAC), (7.0 * SQUARE, 0.0, flight_png.C_SAC)],
    ids=["constant 4 deg, CL-SAC", "square wave +-7 deg, SAC"],
)
def test_a_known_roll_is_drawn_where_the_grid_and_its_labels_put_it(digits, roll_deg, lv, color):
    """The roll's line, column by column where it is flat, is within a pixel of the row that linear interpolation
    between the two labelled grid lines around its value gives; drawn in the law's colour."""
    px = _draw(_series(phi=roll_deg * DEG), lv=lv)
    frame = _frames(px)[0]
    left, top, right, bottom = frame
    grid = _y_grid(px, frame, digits)
    values = [v for _, v in grid]
    assert values == sorted(values, reverse=True) and 0.0 in values and -10.0 in values  # read top to bottom
    cover = _coverage(px[top + 1 : bottom, left + 1 : left + 600], color)  # left of the legend and the note
    levels = sorted(set(np.round(roll_deg, 6)))
    seen = {lev: 0 for lev in levels}
    rows = np.arange(top + 1, bottom)[:, None]
    for j in range(cover.shape[1]):
        c = np.where(cover[:, j] > 0.2, cover[:, j], 0.0)  # (not the faint grid: grey is a little of any colour)
        hit = np.flatnonzero(c > 0.2)
        if not len(hit) or hit[-1] - hit[0] > 3:  # nothing, or a vertical stretch (a change of the square wave)
            continue
        centre = float((rows[:, 0] * c).sum() / c.sum()) + 0.5  # the line's middle, rows as [r, r + 1)
        lev = min(levels, key=lambda v: abs(_at(grid, v) - centre))
        assert abs(_at(grid, lev) + 0.5 - centre) <= 1.0, (j, lev, centre, _at(grid, lev))
        seen[lev] += 1
    assert all(n > 100 for n in seen.values()), seen  # every level found, along much of the panel


def test_each_series_has_its_colour_in_its_panel_and_none_when_it_is_missing():
    """Flat stretches of each series' colour in its own panel (left of the legend); none when the flight lacks it."""
    panels = {
        "um": (0, flight_png.C_CMD),
        "ym_ol": (0, flight_png.C_OL),
        "ym": (0, flight_png.C_CRM),
        "phi": (0, flight_png.C_CLSAC),
        "u": (1, flight_png.C_CLSAC),
        **{k: (2, c) for k, c in flight_png.C_GAINS.items()},
    }
    full = _draw(_series())
    frames = _frames(full)
    for key, (i, color) in panels.items():
        left, top, right, bottom = frames[i]
        region = (slice(top + 2, bottom - 1), slice(left + 2, left + 600))
        run = 3 if key == "um" else 8  # the command is dashed: shorter runs of black (nothing else is black inside)
        assert _solid(full[region], color, run).sum() > 100, key
        without = _draw(_series(**{key: None}))
        assert _frames(without) == frames
        assert _solid(without[region], color, run).sum() == 0, key


def test_a_missing_series_is_said_in_its_panel():
    """ "not recorded by this transport: ym": grey text at the middle right of the roll panel, absent otherwise;
    and a flight with no gains at all says so in the middle of that panel, without y ticks."""

    def note_pixels(px, frame, where):
        left, top, right, bottom = frame
        mid = (top + bottom) // 2
        cols = slice(left + int(0.65 * (right - left)), right) if where == "right" else slice(left + 300, right - 300)
        band = px[mid - 8 : mid + 9, cols]
        grey = (band[..., 0] == band[..., 1]) & (band[..., 1] == band[..., 2])
        return int((grey & (band[..., 0] >= 95) & (band[..., 0] <= 112)).sum())  # the note's #666 text, anti-aliased

    full, no_ym = _draw(_series()), _draw(_series(ym=None))
    frame = _frames(full)[0]
    assert note_pixels(full, frame, "right") == 0
    assert note_pixels(no_ym, frame, "right") > 30
    no_gains = _draw(_series(ke=None, kx=None, ku=None))
    frame = _frames(no_gains)[2]
    assert note_pixels(no_gains, frame, "middle") > 30 and note_pixels(full, frame, "middle") == 0
    left, top, right, bottom = frame
    ticks = (no_gains[top + 5 : bottom - 5, left - 5 : left] == 0).all(axis=-1).any(axis=1)
    assert not ticks.any()  # no y tick marks: nothing to measure


def test_a_mode_switch_is_a_dotted_line_at_its_time_in_every_panel_with_its_name_above(digits):
    """A switch to FAILSAFE at t = 12.0 s: a dotted line in the column the time axis's labelled grid lines give, in
    each panel, and text above the top panel from that column; neither without the switch."""
    mode = np.where(T >= 12.0, 102.0, 101.0)
    px, plain = _draw(_series(mode=mode)), _draw(_series())
    frames = _frames(px)
    col = _at(_x_grid(px, frames, digits), 12.0)
    for _, top, _, bottom in frames:
        dotted = []
        for img in (px, plain):
            strip = _coverage(img[top + 1 : bottom, int(col) - 1 : int(col) + 3], plot_engine.C_MARK)
            dotted.append(int((strip.max(axis=1) > 0.4).sum()))  # rows with a dot (other lines cross it too)
        assert dotted[0] - dotted[1] > 0.3 * (bottom - top), (top, dotted)
    top = frames[0][1]
    dark = px[top - 14 : top - 1].mean(axis=-1) < 128
    assert dark[:, int(col) : int(col) + 60].sum() > 40  # the name, from the line on
    assert not dark[:, int(col) - 40 : int(col) - 1].any()  # (left aligned: nothing before it)


def test_a_spike_in_a_long_series_stays_visible():
    """20,000 points, all zero but one: the line still reaches the spike's value (near the top of the panel)."""
    n = 20_000
    t = np.arange(n) * 0.01
    ke = np.zeros(n)
    ke[12_345] = 1.0
    series = {k: (v if k == "ke" else v[:1].repeat(n)) for k, v in _series(ke=ke).items() if k != "t"}
    px = _draw({**series, "t": t})
    left, top, right, bottom = _frames(px)[2]
    cover = _coverage(px[top + 1 : bottom, left + 1 : right], flight_png.C_GAINS["ke"])
    hit = np.flatnonzero(cover.max(axis=1) > 0.3)
    assert hit[0] < 0.1 * (bottom - top)  # the spike's top: 1.0 among zeros, within the top 5 % margin


def test_nan_and_inf_leave_gaps_not_a_crash(tmp_path, digits):
    """Non-finite values are skipped: the picture is drawn (through the helper's entry point, from the files),
    and the roll's line has a gap where its values are NaN."""
    phi = np.full(N, 4 * DEG)
    phi[1200:1800] = np.nan  # 12 s to 18 s
    u = 3 * DEG * SQUARE
    u[100] = np.inf
    ke = np.full(N, 0.1)
    ke[2000] = -np.inf
    np.savez(tmp_path / "autopilot_series.npz", **_series(phi=phi, u=u, ke=ke))
    png = draw_flight_png(tmp_path, "clsac", 20.0, True, 100.0, 30.0, {"ise_ref": 0.01})
    assert png == tmp_path / "flight.png"
    px = np.asarray(Image.open(png).convert("RGB")).astype(int)
    frames = _frames(px)
    left, top, right, bottom = frames[0]
    cover = _coverage(px[top + 1 : bottom], flight_png.C_CLSAC).max(axis=0) > 0.3  # columns with the roll
    x = _x_grid(px, frames, digits)
    col = lambda t: round(_at(x, t))  # noqa: E731
    assert cover[col(5) : col(11)].all() and not cover[col(12.5) : col(17.5)].any()


def test_no_series_no_picture(tmp_path):
    """No files, or a flight with no step recorded: None, and no flight.png (as with matplotlib)."""
    assert draw_flight_png(tmp_path, "clsac", 20.0, True, 100.0, 30.0, {}) is None
    np.savez(tmp_path / "autopilot_series.npz", **{k: v[:0] for k, v in _series().items()})
    assert draw_flight_png(tmp_path, "clsac", 20.0, True, 100.0, 30.0, {}) is None
    assert not (tmp_path / "flight.png").exists()


# ---------------------------------------------------------------------------------------- ticks
@pytest.mark.parametrize("seed", range(5))
def test_ticks_are_round_numbers_inside_the_range(seed):
    """1, 2, 2.5 or 5 x 10^k apart, inside the range, at most bins + 1 of them and at least two, for ranges of
    any size and sign."""
    rng = np.random.default_rng(seed)
    for _ in range(200):
        size = 10.0 ** rng.integers(-6, 7)
        lo = float(rng.normal() * size)
        hi = lo + float(size * 10.0 ** rng.uniform(-2, 1))  # a range from 1 % to 10 times the values' size
        bins = int(rng.integers(1, 10))
        ticks = nice_ticks(lo, hi, bins)
        assert 2 <= len(ticks) <= max(bins + 1, 3), (lo, hi, bins, ticks)
        assert lo - 1e-9 * (hi - lo) <= ticks[0] and ticks[-1] <= hi + 1e-9 * (hi - lo)
        step = (ticks[-1] - ticks[0]) / (len(ticks) - 1)
        assert np.allclose(np.diff(ticks), step, rtol=1e-6)
        mantissa = step / 10.0 ** math.floor(math.log10(step) + 1e-9)
        assert any(math.isclose(mantissa, m, rel_tol=1e-6) for m in (1, 2, 2.5, 5)), (step, mantissa)
        assert np.allclose(ticks / step, np.round(ticks / step), atol=1e-6)  # multiples of the step
    assert list(nice_ticks(-14.5, 14.0, 9)) == [-10, -5, 0, 5, 10]  # a flight's roll panel
    assert list(nice_ticks(-11.0, 11.0, 9)) == [-10, -7.5, -5, -2.5, 0, 2.5, 5, 7.5, 10]
    assert list(nice_ticks(-11.0, 11.0, 4)) == [-10, 0, 10]
    assert list(nice_ticks(-1.5, 31.5, 9)) == [0, 5, 10, 15, 20, 25, 30]


# ---------------------------------------------------------------------------------------- the review's cases
def test_the_baseline_is_drawn_as_a_fixed_gain_pid_not_as_sac():
    """The fixed-gain PID baseline was titled "SAC (..., L_v=0)" in SAC's red, with K_x = K_u = 0 drawn as adaptive
    gains: its roll is in its own colour, and its gains panel shows its K_p, K_i and K_d (issue 30: not a flat,
    autoscaled K_p line alone) on a range from 0 to above the largest, each at its height."""
    gains_flown = (0.1, 0.1, 0.02)
    img = flight_image(
        _series(),
        name="baseline",
        lv=0.0,
        metrics={},
        u_limit_rad=30 * DEG,
        title="t",
        controller="baseline",
        gains=gains_flown,
    )
    px = np.asarray(img).astype(int)
    frames = _frames(px)
    left, top, right, bottom = frames[0]
    roll = (slice(top + 2, bottom - 1), slice(left + 2, left + 600))
    assert _solid(px[roll], flight_png.C_BASE).sum() > 100 and _solid(px[roll], flight_png.C_SAC).sum() == 0
    left, top, right, bottom = frames[2]
    gains = (slice(top + 2, bottom - 1), slice(left + 2, left + 600))
    rows = {}
    for key in ("ke", "kx", "ku"):  # K_p, K_i, K_d in K_e's, K_x's and K_u's colours (K_i dashed over K_p)
        hit = (px[gains] == ImageColor.getrgb(flight_png.C_GAINS[key])).all(axis=-1)
        assert hit.sum() > 100, key
        rows[key] = np.median(np.nonzero(hit)[0])
    # the range runs from -0.05 x to 1.2 x the largest gain (0.1): K_d = 0.02 sits a fifth of K_p's height up
    height = bottom - 1 - (top + 2)
    y_of = {k: height * (1.2 * 0.1 - v) / (1.25 * 0.1) for k, v in zip(("ke", "kx", "ku"), gains_flown)}
    for key in rows:
        assert abs(rows[key] - y_of[key]) < 4, (key, rows[key], y_of[key])


@pytest.mark.parametrize("name", ["PID_KP", "CLSAC_PID_KP"])  # a recording from before issue 37: its alias
def test_a_parameter_changed_in_flight_steps_the_pid_line_and_is_marked(name):
    """A ground station's PID_KP 0.1 -> 0.3 at 15 s: the K_p line steps there, and the picture marks it."""
    from tools.view.flight_picture import marks

    changes = [{"t_s": 15.0, "name": name, "from": 0.1, "to": 0.3}]
    common = dict(name="b", lv=0.0, metrics={}, u_limit_rad=30 * DEG, title="t", controller="baseline")
    plain = np.asarray(flight_image(_series(), gains=(0.1, 0.1, 0.02), **common)).astype(int)
    moved = np.asarray(
        flight_image(_series(), gains=(0.1, 0.1, 0.02), changes=changes, faults=marks([], changes), **common)
    ).astype(int)
    left, top, right, bottom = _frames(moved)[2]
    region = (slice(top + 2, bottom - 1), slice(left + 2, right - 1))
    rows = np.nonzero((moved[region] == ImageColor.getrgb(flight_png.C_GAINS["ke"])).all(axis=-1))[0]
    assert rows.max() - rows.min() > 0.4 * (bottom - top)  # two heights: 0.1, then 0.3 at the top of the range
    blue = ImageColor.getrgb(flight_png.C_PARAM)  # the change's dashed line, down every panel
    assert (moved == blue).all(axis=-1).sum() > 50 and (plain == blue).all(axis=-1).sum() == 0


def test_mode_lines_go_under_the_legend():
    """A switch under the roll panel's legend (upper right): the legend's box stays white over it, as matplotlib
    draws a legend over the lines."""
    t_switch = 29.0  # right end of the time axis: inside the legend's columns
    px = _draw(_series(mode=np.where(T >= t_switch, 102.0, 101.0)))
    left, top, right, bottom = _frames(px)[0]
    col = int(round(left + (t_switch - (-1.5)) / 33.0 * (right - left)))  # data range 0-30 s, padded 5 %
    box = px[top + 14 : top + 20, col - 3 : col + 4]  # a band inside the legend box, between two entries
    assert _coverage(box, plot_engine.C_MARK).max() < 0.2


def test_mode_names_stay_by_their_lines_and_inside_the_picture():
    """A mode flapping every 0.1 s (300 switches): names are written only where they fit near their own line,
    none past the picture's right edge (they used to be pushed right, one after the other, off the picture)."""
    mode = np.where((np.arange(N) // 10) % 2 == 0, 101.0, 102.0)
    px = _draw(_series(mode=mode))
    top = _frames(px)[0][1]
    dark = px[top - 14 : top - 1].mean(axis=-1) < 128
    assert dark.any() and not dark[:, -3:].any()
    # each name (a run of dark columns, the gaps between letters closed) starts at most 12 px right of a switch
    inked = np.flatnonzero(dark.any(axis=0))
    starts = inked[np.concatenate(([True], np.diff(inked) > 3))]  # a gap of 4 px or more: the next name
    left, _, right, _ = _frames(px)[0]
    switches = left + (T[np.flatnonzero(np.diff(mode)) + 1] + 1.5) / 33.0 * (right - left)
    assert 2 <= len(starts) < 100  # some names, not 300
    for x in starts:
        assert 0 <= x - switches[switches <= x + 1].max() <= 13, x


def test_a_long_time_axis_says_its_multiplier():
    """Time up to 120,000 s (a 33 h flight): the labels 0.0 ... 1.2 need their "1e5" (it was dropped); dark text
    right under the time axis's labels, at the right end."""
    t = np.linspace(0.0, 1.2e5, N)
    px = _draw(_series(t=t))
    left, top, right, bottom = _frames(px)[2]
    below = px[bottom + 20 : bottom + 36, right - 40 : right + 1].mean(axis=-1) < 128
    plain = _draw(_series())[bottom + 20 : bottom + 36, right - 40 : right + 1].mean(axis=-1) < 128
    assert below.sum() > 20 and plain.sum() == 0


@pytest.mark.parametrize(("share", "said"), [(0.003, "<1%"), (0.5, "50%")])
def test_a_rudder_that_touched_its_limit_is_never_said_to_be_there_0_percent_of_the_time(share, said):
    """The note's share of time at the limit: "<1%" below half a percent (it said "0%"), the limit itself as given
    (17.5 deg, not 18)."""
    u = np.where(np.arange(N) < share * N, 17.5 * DEG, 0.0)
    notes = []
    original = plot_engine._note_box
    try:
        plot_engine._note_box = lambda c, ax, lines: notes.extend(lines)
        flight_image(_series(u=u), name="x", lv=20.0, metrics={}, u_limit_rad=17.5 * DEG, title="t")
    finally:
        plot_engine._note_box = original
    assert f"rudder at the 17.5 deg limit {said} of the time" in notes, notes


def test_odd_values_are_drawn_and_said_not_crashed_on():
    """Gains whose range is a denormal (5e-324: the padded range could not be divided into ticks, a math domain
    error), a roll with no finite value ("max|φ|=n/a", not 0) and a blown-up one (1e30 rad: three digits, not 31)."""
    _draw(_series(ke=np.array([0.0, 5e-324] * (N // 2) + [0.0])))
    notes = []
    original = plot_engine._note_box
    try:
        plot_engine._note_box = lambda c, ax, lines: notes.extend(lines)
        for phi in (np.full(N, np.nan), np.full(N, 1e30)):
            flight_image(_series(phi=phi), name="x", lv=20.0, metrics={"ise_ref": 1.0}, u_limit_rad=0.5, title="t")
    finally:
        plot_engine._note_box = original
    assert notes[0] == "ise_ref=1 rad²s, max|φ|=n/a" and notes[1] == "ise_ref=1 rad²s, max|φ|=5.73e+31 deg", notes


# ---------------------------------------------------------------------------------------- issue 35: what a user sees
def _text_mask(s: str, pt: float, rotate: bool = False, ink: int = 90) -> np.ndarray:
    """``s`` drawn alone in DejaVu at ``pt`` points (read upwards if ``rotate``), as the ink a reader sees."""
    font = ImageFont.truetype(plot_engine.font_file(), pt * plot_engine.PX)
    img = Image.new("L", (int(font.getlength(s)) + 40, 60), 0)
    ImageDraw.Draw(img).text((20, 30), s, font=font, fill=255, anchor="lm")
    if rotate:
        img = img.transpose(Image.Transpose.ROTATE_90)
    return _crop(np.asarray(img) > ink)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    h, w = max(a.shape[0], b.shape[0]), max(a.shape[1], b.shape[1])
    pa, pb = np.zeros((h, w), bool), np.zeros((h, w), bool)
    pa[: a.shape[0], : a.shape[1]], pb[: b.shape[0], : b.shape[1]] = a, b
    return (pa & pb).sum() / max((pa | pb).sum(), 1)


def test_a_roll_that_wraps_at_180_deg_is_not_joined_across_the_wrap(digits):
    """A steady roll of 20 deg/s, as ATTITUDE reports it (wrapped to +-180 deg): 180 deg at t = 9 s, then -180.
    The line was joined across the wrap, a vertical stroke over the whole panel: no column of the panel now has the
    roll's colour over more than a tenth of its height, and the line is there just before the wrap near the top
    and just after it near the bottom."""
    phi = ((20.0 * T + 180.0) % 360.0 - 180.0) * DEG
    px = _draw(_series(phi=phi))
    frames = _frames(px)
    left, top, right, bottom = frames[0]
    cover = _coverage(px[top + 1 : bottom, left + 1 : right], flight_png.C_CLSAC) > 0.3
    assert cover.sum(axis=0).max() < 0.1 * (bottom - top), cover.sum(axis=0).max()
    col = lambda t: round(_at(_x_grid(px, frames, digits), t)) - left - 1  # noqa: E731
    before, after = np.flatnonzero(cover[:, col(8.8)]), np.flatnonzero(cover[:, col(9.2)])
    height = bottom - top
    assert before.size and before.max() < 0.15 * height  # 176 deg: near the top (the range is +-198)
    assert after.size and after.min() > 0.85 * height  # -176 deg: near the bottom
    # the same roll unwrapped (a truth roll, 0 to 600 deg) is one unbroken line
    px = _draw(_series(phi=20.0 * T * DEG))
    cover = _coverage(px[top + 1 : bottom, left + 1 : right], flight_png.C_CLSAC) > 0.3
    assert cover[:, col(1.0) : col(24.0)].any(axis=0).all()


def test_gain_spikes_are_clipped_and_marked_not_flattening_the_panel(digits):
    """K_e = 0.1 but for three steps of 330 at t = 15 s: the panel is scaled to the gains' levels (0.1, -0.05 and
    0.02 drawn to scale: the rows of K_u and K_e are 0.08/0.15 of the way from K_e to K_x), the spike drawn as a
    triangle in K_e's colour at the top edge at its time (and nowhere else), and the note gives the clipped
    extremes.  A gain that grows steadily to 330 is not clipped: its line spans the panel."""
    ke = np.full(N, 0.1)
    ke[1500:1503] = 330.0
    notes = []
    original = plot_engine._note_box
    try:
        plot_engine._note_box = lambda c, ax, lines: (notes.extend(lines), original(c, ax, lines))
        px = _draw(_series(ke=ke))
        frames = _frames(px)
        left, top, right, bottom = frames[2]
        rows = {}
        for key in ("ke", "kx", "ku"):
            flat = _solid(px[top + 12 : bottom - 1, left + 2 : left + 600], flight_png.C_GAINS[key])
            rows[key] = float(np.median(np.nonzero(flat)[0]))
        assert rows["kx"] - rows["ke"] > 0.5 * (bottom - top), rows  # not squashed into one line
        assert abs((rows["ku"] - rows["ke"]) / (rows["kx"] - rows["ke"]) - 0.08 / 0.15) < 0.02, rows
        band = _coverage(px[top + 1 : top + 10, left + 1 : right], flight_png.C_GAINS["ke"]) > 0.5
        cols = np.flatnonzero(band.any(axis=0)) + left + 1
        x15 = _at(_x_grid(px, frames, digits), 15.0)
        assert cols.size and np.all(np.abs(cols - x15) <= 5), (cols, x15)
        assert any("330" in s and "K_e" in s for s in notes), notes
        notes.clear()
        px = _draw(_series(ke=np.linspace(0.0, 330.0, N)))
        rows = np.flatnonzero(
            (_coverage(px[top + 1 : bottom, left + 1 : right], flight_png.C_GAINS["ke"]) > 0.5).any(1)
        )
        assert rows.max() - rows.min() > 0.75 * (bottom - top) and not any("clipped" in s for s in notes), notes
    finally:
        plot_engine._note_box = original


def test_fault_labels_that_fall_together_are_merged_not_drawn_over_each_other(digits):
    """Eight faults starting within 0.35 s of each other (about 11 px) and one ending at 20 s: the eight labels were
    written on top of each other.  Left of the first of the eight lines, the ink of the faults' colour is one text as
    drawn alone (all eight names, or the first and "(+7 more)" when they do not fit the panel's height); left of
    the 20 s line, its own label."""
    faults = [(12.0 + 0.05 * k, f"fault stuck={k + 1}") for k in range(8)] + [(20.0, "end stuck=3")]
    img = flight_image(
        _series(phi=np.full(N, 9.5 * DEG)),
        name="clsac",
        lv=20.0,
        metrics={},
        u_limit_rad=30 * DEG,
        title="t",
        faults=faults,
    )
    px = np.asarray(img).astype(int)
    frames = _frames(px)
    left, top, right, bottom = frames[0]
    x = _x_grid(px, frames, digits)
    names = ", ".join(s for _, s in faults[:8])
    for t0, texts in ((12.0, (names, "fault stuck=1 (+7 more)")), (20.0, ("end stuck=3",))):
        col = math.floor(_at(x, t0))
        ink = _crop(_coverage(px[top + 1 : bottom, col - 20 : col], plot_engine.C_FAULT) > 0.35)
        best = max(_iou(ink, _text_mask(s, plot_engine.PT_MODE, rotate=True)) for s in texts)
        assert best > 0.8, (t0, best, ink.shape)


def test_a_mimo_flights_title_names_both_surfaces(tmp_path):
    """A square MIMO flight (aileron and rudder): the title said "(aileron)" alone.  The picture drawn from the
    request the launcher makes for such a flight (``tools.flight.files.png_request``) has, as its top line, exactly
    the title naming both surfaces, drawn alone in the same font."""
    from tools.flight.config import FlightConfig
    from tools.flight.files import png_request

    out = tmp_path / "run-mimo"
    out.mkdir()
    np.savez(out / "autopilot_series.npz", **_series(u2=2 * DEG * SQUARE, beta=np.full(N, 0.5 * DEG)))
    cfg = FlightConfig(plant="jsbsim:c172x:surface=aileron+rudder", lockstep=True)
    png = draw_flight_png(**png_request(cfg, out, "clsac", {}))
    px = np.asarray(Image.open(png).convert("RGB")).astype(int)
    ink = _crop(px[5:45].mean(axis=-1) < 128)
    title = "Flight run-mimo: clsac on c172x-aileron+rudder (aileron and rudder), lockstep, 100 Hz"
    assert _iou(ink, _text_mask(title, plot_engine.PT_SUPTITLE, ink=127)) > 0.8
