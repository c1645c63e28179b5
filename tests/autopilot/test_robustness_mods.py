"""The optional robustness modifications of ClSac (dead-zone, projection, freeze while saturated) and the
anti-windup on every integral channel, on both code paths (SISO floats and the general matrix path)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.clsac import ClSac
from autopilot.config import ClSacConfig, ConfigError

PATHS = [True, False]  # fast (SISO floats), matrix


def _scalar(v) -> float:
    return float(np.asarray(v).reshape(-1)[0])


def _gains(c: ClSac) -> tuple[float, float, float]:
    return _scalar(c.ki_e), _scalar(c.ki_x), _scalar(c.ki_u)


def _drive(c: ClSac, steps: int, y: float, um: float) -> None:
    for _ in range(steps):
        c(y, um)


@pytest.mark.parametrize("fast", PATHS)
def test_defaults_are_the_paper_law_bit_for_bit(fast):
    """Every modification off: the same numbers as a config that never heard of them (fields at their defaults)."""
    base = ClSacConfig()
    assert (base.dead_zone_rad, base.ki_max, base.freeze_when_saturated) == (0.0, None, False)
    a, b = ClSac(base, fast=fast), ClSac(base.with_(dead_zone_rad=0.0, ki_max=None), fast=fast)
    rng = np.random.default_rng(3)
    for y, um in rng.normal(0, 0.3, (500, 2)):
        assert _scalar(a(y, um)) == _scalar(b(y, um))
    assert _gains(a) == _gains(b)


@pytest.mark.parametrize("fast", PATHS)
def test_dead_zone_stops_integral_adaptation_inside_and_not_outside(fast):
    dz = math.radians(1.0)
    c = ClSac(ClSacConfig(lv=0.0, dead_zone_rad=dz, sigma=0.0), fast=fast)
    # First step: x_m = 0 so e = -y; |e| = 0.5 dz < dz: no integral increment at all.
    c(0.5 * dz, 0.2)
    assert _scalar(c.e) == pytest.approx(-0.5 * dz)
    assert _gains(c) == (0.0, 0.0, 0.0)
    # Outside the zone the same law adapts (the increment T e u_m Gamma_Iu is not zero).
    c.reset()
    c(2.0 * dz, 0.2)
    assert _scalar(c.e) == pytest.approx(-2.0 * dz)
    kie, kix, kiu = _gains(c)
    assert kiu == pytest.approx(0.01 * (-2.0 * dz) * 0.2 * 10.0)
    assert kie == pytest.approx(0.01 * (2.0 * dz) ** 2 * 10.0)
    # The same input without a dead-zone adapts identically outside it.
    ref = ClSac(ClSacConfig(lv=0.0, sigma=0.0), fast=fast)
    ref(2.0 * dz, 0.2)
    assert _gains(ref) == _gains(c)


@pytest.mark.parametrize("fast", PATHS)
def test_projection_keeps_every_integral_gain_within_its_bound(fast):
    bound = 0.05
    free = ClSac(ClSacConfig(sigma=0.0), fast=fast)
    proj = ClSac(ClSacConfig(sigma=0.0, ki_max=bound), fast=fast)
    rng = np.random.default_rng(7)
    peak_free = 0.0
    for y, um in rng.normal(0, 0.5, (3000, 2)):
        free(y, um)
        proj(y, um)
        peak_free = max(peak_free, *map(abs, _gains(free)))
        assert all(abs(g) <= bound for g in _gains(proj))
    assert peak_free > 2 * bound  # the bound was reached and held, not idle
    assert max(map(abs, _gains(proj))) == bound


@pytest.mark.parametrize("fast", PATHS)
def test_freeze_when_saturated_skips_every_channel_even_when_it_would_unwind(fast):
    """Conditional integration keeps a channel whose increment pulls u_raw back inside the limit; freezing
    skips it too.  Set up a saturated step with e u_raw < 0 (the increments pull back): K_Ix starts large
    and positive with x_m > 0, so u_raw is far above the limit while e < 0."""
    kw = dict(lv=0.0, sigma=0.0, u_limit_rad=0.01, ki_x0=50.0)
    aw, frz = ClSac(ClSacConfig(**kw), fast=fast), ClSac(ClSacConfig(**kw, freeze_when_saturated=True), fast=fast)
    for c in (aw, frz):
        c(0.0, 1.0)  # x_m grows to > 0, u_raw = K_Ix x_m = 0 this step
        c(0.2, 1.0)  # y > y_m: e < 0 while u_raw = 50 x_m + ... >> limit
        assert c.saturated and _scalar(c.e) < 0 < _scalar(c.u_raw)
    before = ClSac(ClSacConfig(**kw), fast=fast)
    before(0.0, 1.0)
    assert _gains(frz) == _gains(before)  # nothing integrated in the saturated step
    assert _gains(aw)[1] < _gains(before)[1]  # anti-windup alone let K_Ix unwind (e x_m < 0)


@pytest.mark.parametrize("fast", PATHS)
@pytest.mark.parametrize("channel", ["e", "x", "u"])
def test_anti_windup_on_each_integral_channel(fast, channel):
    """Only one channel adapts (the other Gammas 0).  Saturated with e u_raw > 0 (the increment would push u_raw
    further past the limit): with anti-windup that channel's K_I does not move; without, it winds up."""
    gammas = {f"gamma_i{ch}": (10.0 if ch == channel else 0.0) for ch in "exu"}
    gammas.update({f"gamma_p{ch}": 0.0 for ch in "exu"})
    kw = dict(lv=0.0, sigma=0.0, u_limit_rad=1e-4, ki_u0=1.0, **gammas)  # K_Iu(0) = 1: u_raw = u_m, saturated
    on = ClSac(ClSacConfig(**kw), fast=fast)
    off = ClSac(ClSacConfig(**kw, anti_windup=False), fast=fast)
    idx = "exu".index(channel)
    k0 = (0.0, 0.0, 1.0)[idx]
    for c in (on, off):
        for _ in range(200):
            c(-0.1, 0.5)  # roll stays at -0.1 rad below a positive command: e > 0, u_raw > 0, saturated
        assert c.saturated and _scalar(c.e) > 0 and _scalar(c.u_raw) > 0
    assert _gains(on)[idx] == k0
    assert _gains(off)[idx] - k0 > 1e-3  # without anti-windup the same channel winds up


@pytest.mark.parametrize("fast", PATHS)
@pytest.mark.parametrize("channel", ["e", "x", "u"])
def test_anti_windup_keeps_a_channel_that_pulls_back(fast, channel):
    """Saturated with e u_raw < 0: the increment pulls u_raw back towards the limit, so it is integrated."""
    gammas = {f"gamma_i{ch}": (10.0 if ch == channel else 0.0) for ch in "exu"}
    gammas.update({f"gamma_p{ch}": 0.0 for ch in "exu"})
    kw = dict(lv=0.0, sigma=0.0, u_limit_rad=1e-4, ki_u0=1.0, **gammas)
    on = ClSac(ClSacConfig(**kw), fast=fast)
    off = ClSac(ClSacConfig(**kw, anti_windup=False), fast=fast)
    for c in (on, off):
        for _ in range(5):
            c(0.8, 0.5)  # roll above the command: e < 0 while u_raw = u_m > 0 is saturated
        assert c.saturated and _scalar(c.e) < 0 < _scalar(c.u_raw)
    assert _gains(on) == _gains(off)
    if channel == "e":
        assert _gains(on)[0] > 0  # K_Ie' = e^2 Gamma >= 0 pulls back when e u_raw < 0


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(dead_zone_rad=-0.1), "dead_zone_rad"),
        (dict(dead_zone_rad=float("nan")), "dead_zone_rad"),
        (dict(ki_max=0.0), "ki_max"),
        (dict(ki_max=float("inf")), "ki_max"),
    ],
)
def test_bad_modification_values_are_rejected(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        ClSacConfig(**kwargs)
