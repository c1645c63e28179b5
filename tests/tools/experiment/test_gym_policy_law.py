"""tools.experiment.gym.policy_law: a policy trained by tools.experiment.gym.ars, flown as a law (issue 39 item 3)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

from tests._mavlink_procs import run_cli  # noqa: E402


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A tiny ARS run (one iteration, two directions: seconds) with its policy_law.py."""
    out = tmp_path_factory.mktemp("ars")
    r = run_cli(
        "tools.experiment.gym.ars", "--out", str(out), "--iterations", "1", "--directions", "2", "--top", "1",
        timeout=600,
    )  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    assert (out / "policy.json").is_file() and (out / "policy_law.py").is_file()
    return out


def test_the_law_commands_the_policys_actions_on_the_envs_observations(trained):
    import sitl.gym  # noqa: F401 (registers Roll-v0)
    from autopilot import law as laws
    from tools.experiment.gym.ars import Linear

    record = json.loads((trained / "policy.json").read_text())
    policy = Linear.from_dict(record)
    assert np.any(policy.m != 0) and np.any(policy.sigma != 1)  # a trained policy, not the zero one
    cls = laws.load(f"{trained / 'policy_law.py'}:Policy")
    lim = math.radians(30.0)
    law = cls(laws.configure(cls, control_rate_hz=100.0, u_limit_rad=lim))
    # a policy scaled up so that it saturates too: the clip and the servo's last command are exercised
    big = Linear.from_dict({**record, "M": (np.array(record["M"]) * 40.0).tolist()})
    big_law = type("Big", (cls,), {"M": tuple(big.m.ravel().tolist())})(law.config)
    saturated = 0
    for pol, lw in ((policy, law), (big, big_law)):
        env = gymnasium.make("sitl.gym:Roll-v0", duration=5.0, turbulence="light")
        compared, seed = 0, 7
        while compared < 300:  # episodes until 300 steps compared (a poor policy may leave the envelope early)
            obs, _ = env.reset(seed=seed, options={"fault": "effectiveness=0.3@1"})
            lw.reset()
            done = False
            while not done:
                a = pol(obs[None, :])[0]  # the env policy's action (rad), unclipped
                u = lw.step(obs[0], obs[1], obs[2], obs[3])
                want = min(max(float(a[0]), -lim), lim)
                assert abs(u - want) <= 1e-12, (seed, compared, u, want)
                saturated += abs(float(a[0])) > lim
                obs, _r, term, trunc, _info = env.step(a)
                assert lw.u_last == obs[4], (seed, compared, lw.u_last, obs[4])  # the env's u_last, exactly
                compared += 1
                done = term or trunc
            seed += 1
        env.close()
    assert saturated > 0  # the scaled policy did hit the limit


def test_the_law_refuses_a_policy_of_the_wrong_shape():
    from tools.experiment.gym.policy_law import PolicyConfig, PolicyLaw

    bad = type("Bad", (PolicyLaw,), {"M": (1.0, 2.0), "MU": (0.0,) * 5, "SIGMA": (1.0,) * 5})
    with pytest.raises(ValueError, match="M must be 1 x 5"):
        bad(PolicyConfig())


@pytest.mark.e2e
def test_the_policy_flies_in_the_launcher(trained, tmp_path):
    spec = f"{trained / 'policy_law.py'}:Policy"
    r = run_cli(
        "tools.launch", "--lockstep", "--duration", "5", "--controller", spec, "--no-rrd", "--no-png",
        "--out", str(tmp_path / "d"), timeout=600,
    )  # fmt: skip
    assert r.returncode in (0, 3), r.stdout + r.stderr
    s = json.loads((tmp_path / "d" / "summary.json").read_text())
    assert s["law"]["name"] == "ars-policy" and s["law"]["controller"] == spec
    assert isinstance(s["law"]["telemetry_end"]["u_last"], float)


@pytest.mark.e2e
def test_the_policy_flies_in_the_damage_study(trained, tmp_path):
    spec = f"{trained / 'policy_law.py'}:Policy"
    r = run_cli(
        "tools.experiment", "damage", "--plant", "kh2013a", "--controllers", f"baseline,{spec}",
        "--kinds", "effectiveness", "--severity", "effectiveness=0.3", "--runs", "1", "--seed", "1",
        "--out", str(tmp_path / "d2"), "--quiet", timeout=900,
    )  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    s = json.loads((tmp_path / "d2" / "summary.json").read_text())
    assert s["labels"][spec] == "ARS linear policy"
    cells = [c for c in s["cells"] if c["controller"] == spec]
    assert {c["kind"] for c in cells} == {"none", "effectiveness"} and all(c["flights"] == 1 for c in cells)
