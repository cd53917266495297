"""The population generator keeps going past an arm whose plant cannot be recorded, and
says which."""

from __future__ import annotations

import json
import sys

import benchmarks.population as population

REAL_MAKE_ONE = population.make_one


def _second_blows_up(seed, out, samples):
    """The generator's make_one, except that arm 1's plant blows up (as a MuJoCo plant
    driven past its wires' f_max does)."""
    if seed == 1:
        raise FloatingPointError("the simulated arm (arm001.xml) went unstable")
    return REAL_MAKE_ONE(seed, out, samples)


def test_an_arm_whose_plant_blows_up_is_named_and_left_out(tmp_path, monkeypatch, capsys):
    out = tmp_path / "pop"
    out.mkdir()
    # an older line of arm001 (other settings) must not stand in for the arm not recorded
    (out / "manifest.jsonl").write_text(json.dumps({"arm": "arm001", "seed": 1,
                                                    "key": "older"}) + "\n")
    monkeypatch.setattr(population, "make_one", _second_blows_up)
    monkeypatch.setattr(sys, "argv", ["population.py", "--arms", "2", "--samples", "12",
                                      "--out", str(out)])
    population.main()
    said = capsys.readouterr().out
    assert "arm001 not recorded: the simulated arm (arm001.xml) went unstable" in said
    assert "1 not recorded (arm001)" in said.splitlines()[-1]
    lines = [json.loads(t) for t in (out / "manifest.jsonl").read_text().splitlines()]
    assert [d["arm"] for d in lines] == ["arm000"]
    assert lines[0]["rows"] > 0 and (out / lines[0]["recording"]).is_file()
