"""Arrow columns for ``RecordingStream.send_columns``: scalar series, time columns, series styles."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pyarrow as pa
import rerun as rr

from autopilot.shared.telemetry.layout import AIRCRAFT_BOXES, SIM_TIME, WALL_TIME, Rgb, Rgba


class _ArrowBatch:
    """Minimal ComponentBatchLike around a ready pyarrow array (avoids rerun's per-call converters)."""

    __slots__ = ("_array",)

    def __init__(self, array: pa.Array):
        self._array = array

    def as_arrow_array(self) -> pa.Array:
        return self._array


_SCALARS = rr.Scalars.descriptor_scalars()


def scalar_column(values: np.ndarray) -> rr.ComponentColumn:
    """A ``Scalars`` column from an (n,) or (n, k) float array: k series per row (one per instance)."""
    v = np.ascontiguousarray(values, dtype=np.float64)
    n = v.shape[0]
    k = 1 if v.ndim == 1 else v.shape[1]
    offsets = np.arange(0, n * k + 1, k, dtype=np.int32)
    return rr.ComponentColumn(_SCALARS, _ArrowBatch(pa.array(v.reshape(-1), pa.float64())), offsets=offsets)


def sim_time_column(seconds: np.ndarray, timeline: str = SIM_TIME) -> rr.TimeColumn:
    """Duration column rounded to the nanosecond.

    rerun's own float path truncates (``(t * 1e9).astype(int)``), which maps 0.0075 s to 7499999 ns:
    two processes computing the same instant differently would then land on different indices.
    """
    ns = np.rint(np.asarray(seconds, dtype=np.float64) * 1e9).astype(np.int64)
    return rr.TimeColumn(timeline, duration=ns.astype("timedelta64[ns]"))


def wall_time_column(epoch_seconds: np.ndarray, timeline: str = WALL_TIME) -> rr.TimeColumn:
    """Timestamp column from ``time.time()`` seconds, rounded to the nanosecond."""
    ns = np.rint(np.asarray(epoch_seconds, dtype=np.float64) * 1e9).astype(np.int64)
    return rr.TimeColumn(timeline, timestamp=ns.astype("datetime64[ns]"))


def series_style(
    labels: Sequence[str], colors: Sequence[Rgb], step: bool = False, points: bool = False
) -> rr.SeriesLines | rr.SeriesPoints:
    """Legend names and colours of the series of one entity; ``step`` draws staircases, ``points`` markers only
    (a triangle per event)."""
    if points:
        n = len(labels)
        return rr.SeriesPoints(
            names=list(labels), colors=[list(c) for c in colors], markers=["Up"] * n, marker_sizes=[6.0] * n
        )
    return rr.SeriesLines(
        names=list(labels), colors=[list(c) for c in colors], interpolation_mode="StepAfter" if step else None
    )


def roll_quaternions(roll_rad: np.ndarray) -> np.ndarray:
    """(n, 4) unit quaternions (x, y, z, w) of rotations by ``roll_rad`` about the body x axis:
    q = (sin(phi/2) e_x, cos(phi/2)), the rotation R_x(phi) that takes the body axes to the level frame (FRD:
    positive roll puts the right wing down)."""
    half = 0.5 * np.asarray(roll_rad, dtype=np.float64)
    q = np.zeros((half.shape[0], 4))
    q[:, 0] = np.sin(half)
    q[:, 3] = np.cos(half)
    return q


def attitude_quaternions(roll_rad: np.ndarray, pitch_rad: np.ndarray) -> np.ndarray:
    """(n, 4) unit quaternions (x, y, z, w) of R_y(theta) R_x(phi), the Euler ZYX attitude with the heading left
    out: q = q_y(theta) q_x(phi) = (c_theta s_phi, s_theta c_phi, -s_theta s_phi, c_theta c_phi), halves of the
    angles (FRD: positive pitch puts the nose up)."""
    hr = 0.5 * np.asarray(roll_rad, dtype=np.float64)
    hp = 0.5 * np.asarray(pitch_rad, dtype=np.float64)
    sr, cr, sp, cp = np.sin(hr), np.cos(hr), np.sin(hp), np.cos(hp)
    return np.stack([cp * sr, sp * cr, -sp * sr, cp * cr], axis=1)


def pose_columns(roll_rad: np.ndarray, pitch_rad: np.ndarray | None = None):
    """``Transform3D`` columns (one quaternion per row) of the aircraft at ``roll_rad`` (and ``pitch_rad``)."""
    q = roll_quaternions(roll_rad) if pitch_rad is None else attitude_quaternions(roll_rad, pitch_rad)
    return rr.Transform3D.columns(quaternion=q)


def aircraft_shape(color: Rgba) -> rr.Boxes3D:
    """The aircraft (``AIRCRAFT_BOXES``: fuselage, wing, tailplane, fin) as boxes in ``color``: solid when opaque,
    a translucent fill with its edges (a ghost) when alpha < 255."""
    return rr.Boxes3D(
        centers=[c for _, c, _ in AIRCRAFT_BOXES],
        half_sizes=[h for _, _, h in AIRCRAFT_BOXES],
        colors=[list(color)] * len(AIRCRAFT_BOXES),
        fill_mode="Solid" if color[3] == 255 else "TransparentFillMajorWireframe",
    )
