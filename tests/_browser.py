"""The headless-Chromium driver of the web-viewer tests (``tools.bench._browser``, which the viewer bench uses too),
and what those tests read off a screenshot of the Flight tab (``test_browser_viewer.py``: a live flight;
``test_browser_recording.py``: saved recordings)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from autopilot.shared.telemetry.layout import PURPLE, SKY
from tools.bench._browser import (  # noqa: F401
    Browser,
    BrowserError,
    chromium_argv,
    chromium_path,
    decode_viewer_state,
    free_tcp_port,
    viewer_state,
)

LOAD_TIMEOUT_S = 240.0  # SwiftShader on a loaded 2-core machine: the viewer draws in 20-60 s

# Regions of the 1600x1000 Flight tab, as fractions (x0, y0, x1, y1) of the screenshot.
ROLL_PLOT = (0.0, 0.08, 0.70, 0.30)
ATTITUDE_3D = (0.74, 0.08, 1.0, 0.32)
GAINS_ROW = (0.0, 0.50, 1.0, 0.66)
BOTTOM_ROW = (0.0, 0.82, 0.50, 0.98)
LINE_PIXELS = 250  # a drawn line holds hundreds of pixels of its colour; a legend's dot some tens


def region(img: np.ndarray, box) -> np.ndarray:
    h, w = img.shape[:2]
    x0, y0, x1, y1 = box
    return img[int(y0 * h) : int(y1 * h), int(x0 * w) : int(x1 * w), :3].astype(int)


def colour_pixels(img: np.ndarray, box, rgb, tol: int = 12) -> int:
    """Pixels of ``box`` within ``tol`` of ``rgb`` on every channel."""
    return int(np.all(np.abs(region(img, box) - np.array(rgb)) <= tol, axis=-1).sum())


def lane_pixels(img: np.ndarray, box) -> int:
    """Pixels of the GREEN family (the lanes draw it blended with the background): G well above R and B."""
    r = region(img, box)
    return int(((r[..., 1] - r[..., 0] > 80) & (r[..., 1] - r[..., 2] > 20)).sum())


def aircraft_pixels(img: np.ndarray, box) -> int:
    """Pixels of the lit purple aircraft (R above G, B above G) in the 3D view."""
    r = region(img, box)
    return int(((r[..., 0] - r[..., 1] > 30) & (r[..., 2] - r[..., 1] > 15)).sum())


def drawn(png: bytes) -> dict[str, int]:
    import io

    from PIL import Image

    img = np.array(Image.open(io.BytesIO(png)).convert("RGB"))
    return {
        "roll truth line": colour_pixels(img, ROLL_PLOT, PURPLE),
        "gains lines": colour_pixels(img, GAINS_ROW, SKY),
        "aircraft in 3D": aircraft_pixels(img, ATTITUDE_3D),
        "mode lanes": lane_pixels(img, BOTTOM_ROW),
    }


def plots_drawn(counts: dict[str, int]) -> bool:
    return (
        counts["roll truth line"] >= LINE_PIXELS
        and counts["gains lines"] >= LINE_PIXELS
        and counts["aircraft in 3D"] >= 100
        and counts["mode lanes"] >= 5000
    )


def viewer_lags(b: Browser, n: int = 5, every_s: float = 2.0) -> list[float]:
    """``n`` readings, ``every_s`` apart, of how old the newest sample the page's viewer holds is: the host clock
    minus the newest ``wall_time`` of the recording (every row carries its sample's host clock)."""
    lags = []
    for _ in range(n):
        b.pump(every_s)
        state = viewer_state(b)
        recs = [r for r in (state.recordings if state else []) if r.store_id.startswith("Recording:")]
        ends = [r.ranges["wall_time"][1] for r in recs if "wall_time" in r.ranges]
        if ends:
            lags.append(time.time() - max(ends) * 1e-9)
    return lags


def view_in_browser(url: str, shot: Path, lags: bool = False, holds=None) -> tuple:
    """Open ``url`` in headless Chromium, screenshot until the plots are drawn; (pixel counts, errors, internet,
    the viewer's lag behind the flight if ``lags``: ``viewer_lags`` once drawn, the viewer's state at the end: once
    ``holds(state)`` is true if given, for at most ``LOAD_TIMEOUT_S``)."""
    with Browser(1600, 1000) as b:
        b.open(url)
        state = {}

        def check():
            state["counts"] = drawn(b.screenshot(shot))
            return plots_drawn(state["counts"])

        b.wait_until(check, LOAD_TIMEOUT_S, poll_s=3.0)
        b.pump(3.0)  # a few more seconds of the live page: errors after drawing count too
        behind = viewer_lags(b) if lags else []
        if holds is not None:
            b.wait_until(lambda: holds(viewer_state(b)), LOAD_TIMEOUT_S, poll_s=2.0)
        return state["counts"], b.errors(), b.external, behind, viewer_state(b)


def wing_slope(mask: np.ndarray) -> float:
    """The slope dy/dx (image rows grow downwards) of the line through a shape's pixels: the wing dominates it."""
    ys, xs = np.nonzero(mask)
    assert len(xs) > 100, len(xs)
    return float(np.polyfit(xs, ys, 1)[0])
