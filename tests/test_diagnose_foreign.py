"""The diagnosis on an arm it has never seen, from recordings another tool wrote.

`tests/foreign_arm.py` simulates a planar 3-link, 6-muscle arm with no pinocchio, no via
points and the paper's opposite elastic sign convention; the diagnosis gets only the two
recordings. It must name the concealed effect first, improve the fit, and name nothing
when nothing is concealed.
"""

from __future__ import annotations

import pytest

from pimbs_learn.diagnosis.run import diagnose
from tests.foreign_arm import record

CASES = [  # (effect, size, muscle or joint index, expected muscles or joints)
    (None, 0.0, 0, None),
    ("tendon_friction", 0.12, 0, None),
    ("tension_offset", 10.0, 2, ["mus2"]),
    ("thermal_drift", 0.5, 0, None),
    ("elastic_stiffness", 0.7, 0, None),
    ("joint_offset", 0.03, 1, ["knee"]),
    ("link_mass", 1.3, 2, None),
]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    path = tmp_path_factory.mktemp("foreign") / "sim.parquet"
    record(path, 300, 3)
    return path


@pytest.mark.parametrize(("effect", "size", "unit", "where"), CASES,
                         ids=[c[0] or "none" for c in CASES])
def test_foreign_arm(tmp_path, reference, effect, size, unit, where):
    real = tmp_path / "real.parquet"
    record(real, 300, 3, effect, size, unit)
    result, _ = diagnose(real, reference)
    assert result["model"]["kappa"][0] > 0  # it learned the other tool's sign convention
    named = result["effects"]
    if effect is None:
        assert named == []
        return
    assert named and named[0]["name"] == effect, [e["name"] for e in named]
    if where is not None:
        assert (named[0]["muscles"] or named[0]["joints"]) == where
    assert result["fit"]["after"] < 0.9 * result["fit"]["before"]
