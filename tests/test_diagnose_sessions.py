"""Two recordings of one arm diagnosed together: each session homes its motors anew.

A collection zeroes the motors' positions at its start, so a second session on the same arm
reads every muscle's length shifted by a constant of its own. The body (routing, gravity,
loadcells) is the same; the diagnosis must not read the shift as missing physics.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

from pimbs_arm.model import ArmModel
from pimbs_learn.diagnosis.run import diagnose
from pimbs_recording.format import read_recording, write_recording
from pimbs_sim.effects import parse_effect
from pimbs_sim.simulate import simulate

ROBOT = "two-link-4-muscle"


def _sessions(tmp_path, conceal: list[str], shift_m: float):
    """(reals, references): 80 then 30 ATL poses; the second session's lengths read
    ``shift_m`` × (1 … −1) across the muscles off the first's zero."""
    arm = ArmModel.load(ROBOT)
    effects = tuple(parse_effect(c, seed=1) for c in conceal)
    reals, refs = [], []
    for tag, n, seed in (("1", 80, 1), ("2", 30, 2)):
        for kind, hidden, noise_seed, out in (("ref", (), seed + 100, refs),
                                              ("real", effects, seed, reals)):
            data, meta = simulate(arm, n, seed=seed, noise_seed=noise_seed, map_kind="atl",
                                  effects=hidden)
            path = tmp_path / f"{kind}{tag}.parquet"
            write_recording(path, data, meta)
            out.append(path)
    rec = read_recording(reals[1])
    m = len(rec.muscles)
    column = rec.table.column("length").combine_chunks()
    length = np.asarray(column.flatten()).reshape(-1, m) + shift_m * np.linspace(1, -1, m)
    table = rec.table.set_column(rec.table.column_names.index("length"), "length",
                                 pa.FixedSizeListArray.from_arrays(pa.array(length.ravel()), m))
    write_recording(reals[1], table, rec.meta)
    return reals, refs


@pytest.mark.parametrize("conceal,named", [([], []),
                                           (["tension_offset:12,muscles=m1"],
                                            ["tension_offset"])])
def test_a_session_homed_anew_is_no_physics(tmp_path, conceal, named):
    reals, refs = _sessions(tmp_path, conceal, 0.003)
    result, _ = diagnose(reals, refs, robot=ROBOT)
    assert [e["name"] for e in result["effects"]] == named, result["effects"]
    assert result["ambiguous"] == [] and result["unexplained"] == [], result["unexplained"]
    assert result["residual"]["consistent_with_noise"]


def test_the_noise_estimate_of_two_sessions_ignores_their_homing(tmp_path):
    """The sensors' noise levels that weigh every length are estimated with each session's
    own length constant: a second session homed 3 mm off must not read as 20 N of
    loadcell noise (it did when the estimate held one constant for both)."""
    noise = {}
    for shift in (0.0, 0.003):
        folder = tmp_path / f"shift{shift}"
        folder.mkdir()
        reals, refs = _sessions(folder, [], shift)
        result, _ = diagnose(reals, refs, robot=ROBOT)
        noise[shift] = result["model"]["noise_estimate"]
    assert noise[0.003]["tension_N"] == pytest.approx(noise[0.0]["tension_N"], rel=0.05)
    assert noise[0.003]["length_m"] == pytest.approx(noise[0.0]["length_m"], rel=0.05)
    assert noise[0.003]["tension_N"] < 1.0  # the simulated loadcells' noise is 0.3 N


def test_a_constant_between_sessions_is_not_left_as_structure():
    """Each session zeroes its loadcells and homes its motors at its start, and two sessions
    seldom share loads and temperatures: a residual that differs between them by a
    constant would read as a dependence on temperature. The test of what is left holds a
    constant per recording in both of its models; within a session, a residual that
    follows the temperature is still structure."""
    from pimbs_learn.diagnosis.leftover import _baseline, _group_tests, _groups
    from pimbs_learn.diagnosis.model import Samples

    rng = np.random.default_rng(0)
    n, m = 130, 4
    session = (np.arange(n) >= 100).astype(int)
    temperature = np.where(session == 1, 45.0, 30.0)[:, None] + rng.normal(0, 1.0, (n, m))
    data = Samples(theta=rng.uniform(-1, 1, (n, 2)), tension=np.zeros((n, m)),
                   length=np.zeros((n, m)), temperature=temperature,
                   approach=np.zeros((n, m)), tau=np.zeros((n, 2)),
                   time=np.where(session == 1, np.arange(n) - 100, np.arange(n)) * 4.0,
                   sample=np.arange(n), session=session)
    groups = _groups(data, ["j0", "j1"], True)
    shifted = 0.5 * session + rng.normal(0, 0.05, n)
    one = np.ones((n, 1))
    assert _group_tests(shifted, groups, one)["temperature"][1] < 1e-10  # the old reading
    assert _group_tests(shifted, groups, _baseline(data))["temperature"][1] > 1e-3
    warm = shifted + 0.05 * (data.temperature.mean(1) - 30.0)
    assert _group_tests(warm, groups, _baseline(data))["temperature"][1] < 1e-6
