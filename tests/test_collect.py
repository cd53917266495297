"""`pimbs collect`: the routine's parts, then hardware-in-the-loop runs over the mock bus.

HIL runs use the simulated boards on a fresh python-can virtual channel each (``open_arm``
makes one per run) at 20x speed; signals (Ctrl-C, kill -9) need a real subprocess.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import pimbs_recording.format as recording
from pimbs_arm.model import ArmModel
from pimbs_cli.main import main
from pimbs_hw.collection.estimate import estimate_theta
from pimbs_hw.collection.link import Reading
from pimbs_hw.collection.plan import CollectionPlan
from pimbs_hw.collection.settle import SettleConfig, SettleDetector
from pimbs_recording.format import RecordingError, read_recording
from pimbs_sim.effects import parse_effect
from pimbs_sim.simulate import simulate

FAST = ["--mock-speed", "20", "--settle-window", "0.06"]


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load("two-link-4-muscle")


def _collect(out: Path, *args: str, port: str = "virtual"):
    return CliRunner().invoke(main, ["collect", "--port", port, "--out", str(out), *FAST,
                                     *map(str, args)])


def _balance_residual(arm: ArmModel, rec) -> np.ndarray:
    """−Gᵀf − τ per row (zero where the model and the readings agree)."""
    G = arm.muscle_jacobian(rec.theta)
    return -np.einsum("bmn,bm->bn", G, rec.tension) - rec.tau_gravity


# ------------------------------------------------------------------------------ the parts
def test_plan_commands_the_poses_and_floors_of_simulate(arm):
    plan = CollectionPlan(arm, 25, seed=5)
    data, _ = simulate(arm, 25, "atl", seed=5, noise=0.0)
    np.testing.assert_array_equal(plan.poses, data["theta_command"])
    draws = np.random.default_rng([5, 1])  # simulate draws one row of floors per sample
    np.testing.assert_array_equal(plan.f_min, [draws.uniform(10, 300, 4) for _ in range(25)])
    assert CollectionPlan(arm, 3, seed=5, map_kind="al").f_min.max() == 10.0  # f_floor


def test_slack_removal_holds_the_pose_with_qp_tensions(arm):
    plan = CollectionPlan(arm, 6, seed=1)
    for i in range(6):
        t = plan.target(i)
        assert t.held.sum() == arm.n_joints
        assert np.linalg.matrix_rank(arm.muscle_jacobian(t.theta)[t.held]) == arm.n_joints
        eq = arm.equilibrium(list(t.hold_mode), t.hold_command, theta0=t.theta)
        np.testing.assert_allclose(eq.theta, t.theta, atol=1e-7)
        np.testing.assert_allclose(eq.tension, t.tension, rtol=1e-5)
        assert (t.tension >= t.f_min - 1e-6).all()


def _reading(length, tension):
    return Reading(np.asarray(length, float), np.asarray(tension, float), np.full(2, 25.0))


def test_settle_detector_needs_quiet_and_reached():
    cfg = SettleConfig(tension_tol=1.0, length_tol=3e-5, window=0.1)
    is_length = np.array([True, False])
    rng = np.random.default_rng(0)
    command = np.array([0.01, 100.0])

    def run(signal_fn) -> float | None:
        det = SettleDetector(cfg, is_length, command)
        for k in range(200):
            t = k * 0.01
            length, tension = signal_fn(t)
            if det.push(t, _reading([length, 0.0], [5.0, tension + rng.normal(0, 0.3)])):
                return t
        return None

    # noisy but at the command: settles after one window
    assert run(lambda t: (0.01, 100.0)) == pytest.approx(0.1, abs=0.02)
    # first-order approach (tau 0.2 s): settles only once close
    t = run(lambda t: (0.01 * (1 - np.exp(-t / 0.2)), 100.0 * (1 - np.exp(-t / 0.2))))
    assert t is not None and t > 0.8
    # quiet but off the command (e.g. a clamped tension): never settled
    assert run(lambda t: (0.01, 90.0)) is None


def test_theta_estimate_inverts_the_length_model(arm):
    theta = np.array([0.31, -0.22])
    f = arm.tension_distribution(theta, 40.0)
    est = estimate_theta(arm, arm.length(theta, f), f, theta0=np.zeros(2))
    np.testing.assert_allclose(est, theta, atol=1e-8)


# ------------------------------------------------------------------- HIL over the mock bus
def test_complete_collection_is_valid_and_obeys_the_statics(arm, tmp_path):
    out = tmp_path / "x.parquet"
    res = _collect(out, "--samples", 8, "--seed", 4)
    assert res.exit_code == 0, res.output
    assert "collection complete" in res.output
    rec = read_recording(out)
    assert rec.n_rows == 8 and rec.sample.tolist() == list(range(8))
    np.testing.assert_array_equal(rec.theta_command, CollectionPlan(arm, 8, 4).poses)
    assert rec.source == "simulation" and rec.meta["theta_source"] == "joint_encoders"
    assert rec.meta["seed"] == 4 and rec.meta["port"] == "virtual"
    assert rec.array("settled").all()
    # the pose is reached and held; physics: −Gᵀf ≈ τ within the sensor noise
    # (0.3 N loadcell noise, 0.25 N counts, averaged over the settle window)
    assert np.abs(rec.theta - rec.theta_command).max() < 2e-3
    assert np.abs(_balance_residual(arm, rec)).max() < 0.05
    assert np.abs(rec.tau_gravity).max() > 1.0
    assert (rec.tension >= CollectionPlan(arm, 8, 4).f_min - 1.5).all()
    assert set(np.unique(rec.approach)) <= {-1, 0, 1} and (rec.approach != 0).any()
    # a different sequence cannot be spliced onto this file
    res = _collect(out, "--samples", 8, "--seed", 5, "--resume")
    assert res.exit_code == 1 and "--seed 4" in res.output and "Traceback" not in res.output
    res = _collect(out, "--samples", 8, "--seed", 4)
    assert res.exit_code == 1 and "--resume" in res.output


def test_the_quasi_static_arm_is_not_waited_for_where_it_cannot_swing(arm, tmp_path,
                                                                       monkeypatch):
    """Before each move, and before its wires are loaded, a swinging arm must come to rest;
    the built-in quasi-static arm says it is at rest once its equilibrium is solved (it never
    overshoots it), so the routine never judges its rest from readings (its joints creep on
    toward the pose while its wires are loaded, and the final settle waits for them), and
    its held wires load at the length rate (still in steps of a tension command's size). A
    MuJoCo plant, like a real arm, says nothing and gets the readings' rest check every
    time."""
    import pimbs_hw.collection.routine as routine
    from pimbs_hw.collection.move import MoveConfig
    from pimbs_hw.collection.resume import collection_meta, open_recording
    from pimbs_hw.collection.session import open_link

    rests = []
    real = routine.hold_until_settled

    def counting(link, mode, command, config, *args, **kwargs):
        rests.append(np.isinf(np.atleast_1d(config.tension_tol)).all())
        return real(link, mode, command, config, *args, **kwargs)

    monkeypatch.setattr(routine, "hold_until_settled", counting)
    plan, settle, moves = CollectionPlan(arm, 3, seed=4), SettleConfig(window=0.06), \
        MoveConfig(speed=20)
    meta = collection_meta(arm, plan.meta(), port="virtual", simulated=True,
                           settle=settle.meta(), move=moves.meta())
    writer, start = open_recording(tmp_path / "q.parquet", meta, resume=False)
    with open_link("virtual", arm.robot, speed=20) as link:
        assert link.quasi_static and link.at_rest() in (True, False)
        collector = routine.Collector(link, arm, plan, writer, start, settle, move=moves)
        assert collector.move.quasi_static
        assert collector.run().written == 3
    assert len(rests) == 6 and not any(rests)  # each sample's overshoot and final settle
    with open_link("virtual", arm.robot, speed=20,
                   conceal=["tendon_friction:0.1"]) as link:  # friction couples the loops
        assert not link.quasi_static and link.at_rest() is None


def test_arm_without_joint_encoders_records_the_model_estimate(tmp_path):
    arm5 = ArmModel.load("left-arm-5dof")
    out = tmp_path / "5.parquet"
    res = _collect(out, "--robot", "left-arm-5dof", "--samples", 3, "--seed", 1)
    assert res.exit_code == 0, res.output
    rec = read_recording(out)
    assert rec.meta["theta_source"] == "model" and rec.n_rows == 3
    assert np.abs(rec.theta - rec.theta_command).max() < 3e-3  # held well-conditioned
    assert np.abs(_balance_residual(arm5, rec)).max() < 0.05


def test_unsettled_samples_are_recorded_flagged_and_warned(tmp_path):
    out = tmp_path / "u.parquet"
    res = _collect(out, "--samples", 2, "--settle-tol", 1e-6, "--settle-timeout", 0.15)
    assert res.exit_code == 0, res.output
    assert "did not settle within 0.15 s" in res.output and "2 unsettled" in res.output
    rec = read_recording(out)
    assert rec.n_rows == 2 and not rec.array("settled").any()


@pytest.mark.parametrize("fault, muscle, kept, stop", [
    ("silent-board:m1@5", "m1", 5, "BoardSilent"),
    ("overheat:m2@3", "m2", 3, "Overheat"),
])
def test_board_failure_mid_run_stops_safely_and_keeps_samples(tmp_path, fault, muscle, kept,
                                                              stop):
    out = tmp_path / "f.parquet"
    res = _collect(out, "--samples", kept + 4, "--fault", fault)
    assert res.exit_code == 1, res.output
    assert stop in res.output and f"muscle {muscle}" in res.output
    assert "relaxed" in res.output and "--resume" in res.output
    assert "Traceback" not in res.output
    assert read_recording(out).sample.tolist() == list(range(kept))


def test_concealed_offset_pairs_with_simulate_and_shows(arm, tmp_path):
    out = tmp_path / "c.parquet"
    n, seed = 10, 6
    res = _collect(out, "--samples", n, "--seed", seed, "--conceal",
                   "tension_offset:20,muscles=m1")
    assert res.exit_code == 0, res.output
    real = read_recording(out)
    assert "tension_offset" not in str(real.meta)  # concealed: labelled nowhere
    sim = tmp_path / "sim.parquet"  # `pimbs simulate` of the same seed, no effect
    assert CliRunner().invoke(main, ["simulate", "--samples", n, "--seed", seed,
                                     "--out", str(sim)]).exit_code == 0
    rec = read_recording(sim)
    clean = {k: rec.array(k) for k in ("theta", "tension", "tau_gravity", "theta_command",
                                       "sample")}
    twin, _ = simulate(arm, n, "atl", seed=seed,
                       effects=(parse_effect("tension_offset:20,muscles=m1"),))
    np.testing.assert_array_equal(real.theta_command, clean["theta_command"])
    np.testing.assert_array_equal(real.sample, clean["sample"])

    def offset_of_m1(theta, tension, tau):
        """Least-squares bias b of m1's reading: −Gᵀ(f − b e₁) = τ."""
        G1 = arm.muscle_jacobian(theta)[:, 1, :]
        r = -np.einsum("bmn,bm->bn", arm.muscle_jacobian(theta), tension) - tau
        return float(-(G1 * r).sum() / (G1 * G1).sum())

    assert offset_of_m1(real.theta, real.tension, real.tau_gravity) == pytest.approx(20, abs=2)
    assert offset_of_m1(twin["theta"], twin["tension"], twin["tau_gravity"]) == pytest.approx(
        20, abs=2)
    assert abs(offset_of_m1(clean["theta"], clean["tension"], clean["tau_gravity"])) < 2


def test_concealed_friction_has_definite_approaches_and_is_diagnosed(arm, tmp_path):
    """Each muscle's last motion overshoots and comes back in a seeded direction (both signs),
    beyond the friction band: the capstan friction is then what the diagnosis names."""
    from pimbs_learn.diagnosis.run import diagnose

    out, n, seed = tmp_path / "fr.parquet", 40, 3
    # 5x, not 20x: at 20x the mock's equilibrium solver (tens of ms of wall time) lags the
    # sped-up plant so much that its tension servo through the friction oscillates
    res = _collect(out, "--samples", n, "--seed", seed, "--conceal", "tendon_friction:0.15",
                   "--mock-speed", 5)
    assert res.exit_code == 0, res.output
    real = read_recording(out)
    # with friction the arm can run off a pose; the collection then gives that one pose up,
    # says so, and goes on (how often depends on how the solver's lag meets the servo, so
    # it may differ from run to run): the rows recorded are what is checked
    given_up = n - real.n_rows
    assert given_up <= 2 and res.output.count("given up") == given_up, res.output
    plan = CollectionPlan(arm, n, seed)
    planned = np.array([plan.target(int(i)).approach for i in real.sample])
    assert set(np.unique(real.approach)) == {-1, 1}
    assert (real.approach > 0).sum(0).min() >= 5 and (real.approach < 0).sum(0).min() >= 5
    assert (real.approach == planned).mean() > 0.95  # recorded = the planned last motion
    sim = tmp_path / "sim.parquet"
    assert CliRunner().invoke(main, ["simulate", "--samples", n, "--seed", seed,
                                     "--out", str(sim)]).exit_code == 0
    result, _ = diagnose(real, read_recording(sim))
    names = [e["name"] for e in result["effects"]]
    assert names and names[0] == "tendon_friction", (names, result["candidates"])
    assert result["fit"]["after"] < 0.5 * result["fit"]["before"]
    mu = [m["mu"] for m in result["effects"][0]["parameters"].values()]
    assert np.allclose(mu, 0.15, atol=0.03), mu


@pytest.mark.parametrize("sig, rc", [(signal.SIGINT, 130), (signal.SIGKILL, -9)])
def test_interrupted_run_resumes_to_the_same_poses(arm, tmp_path, sig, rc):
    out = tmp_path / "i.parquet"
    n, seed = 10, 7
    args = [sys.executable, "-m", "pimbs_cli.main", "collect", "--port", "virtual", "--samples",
            str(n), "--seed", str(seed), "--out", str(out), *FAST]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            cwd=Path(__file__).parents[1])
    deadline = time.monotonic() + 40
    while time.monotonic() < deadline:
        try:
            if read_recording(out).n_rows >= 3:
                break
        except RecordingError:
            pass
        time.sleep(0.05)
    os.kill(proc.pid, sig)
    output = proc.communicate(timeout=20)[0]
    assert proc.returncode == rc, output
    if sig == signal.SIGINT:
        assert "interrupted" in output and "Traceback" not in output
    partial = read_recording(out)  # valid after a clean stop and after kill -9
    assert 3 <= partial.n_rows < n

    res = _collect(out, "--samples", n, "--seed", seed, "--resume")
    assert res.exit_code == 0, res.output
    rec = read_recording(out)
    assert rec.sample.tolist() == list(range(n))
    np.testing.assert_array_equal(rec.theta_command, CollectionPlan(arm, n, seed).poses)
    assert np.abs(_balance_residual(arm, rec)).max() < 0.05


def test_full_disk_keeps_what_was_written(tmp_path, monkeypatch):
    real_write, calls = recording._atomic_write, []

    def filling_disk(table, path):
        calls.append(path)
        if len(calls) > 3:
            raise recording.RecordingWriteError(28, f"could not write {path}: No space left "
                                                    "on device; the recording already on disk "
                                                    "is unchanged")
        real_write(table, path)

    monkeypatch.setattr(recording, "_atomic_write", filling_disk)
    out = tmp_path / "d.parquet"
    res = _collect(out, "--samples", 6)
    assert res.exit_code == 1 and "No space left" in res.output
    assert "Free disk space" in res.output and "Traceback" not in res.output
    assert read_recording(out).n_rows == 3


def test_user_errors_say_what_to_do(tmp_path, monkeypatch):
    out = tmp_path / "e.parquet"
    res = _collect(out, "--fault", "silent-board:m1@5", port="can0")
    assert res.exit_code == 1 and "simulated arm only" in res.output
    res = _collect(out, "--fault", "silent-board:m9@5")
    assert res.exit_code == 1 and "unknown muscle 'm9'" in res.output
    # a bus where no board answers (python-can config from the environment)
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    monkeypatch.setenv("CAN_CHANNEL", f"empty-{os.getpid()}")
    res = _collect(out, "--samples", 2, port="default")
    assert res.exit_code == 1 and "no working arm on port 'default'" in res.output
    assert "--robot two-link-4-muscle" in res.output and "Traceback" not in res.output
    assert not out.exists()


def test_robot_file_that_does_not_match_the_boards(tmp_path, monkeypatch):
    """Boards of two-link-4-muscle on the bus, a description with a fifth muscle (board 5)."""
    import yaml

    from pimbs_calibration.description import load_robot
    from pimbs_hw.mock import MockArm

    robots = Path(load_robot("two-link-4-muscle").muscle_path).parent
    (tmp_path / "two-link-4-muscle.urdf").write_text(
        (robots / "two-link-4-muscle.urdf").read_text())
    desc = yaml.safe_load((robots / "two-link-4-muscle.muscles.yaml").read_text())
    desc["muscles"].append({**desc["muscles"][0], "name": "m4", "board_id": 5})
    wrong = tmp_path / "wrong.muscles.yaml"
    wrong.write_text(yaml.safe_dump(desc))
    channel = f"mismatch-{os.getpid()}"
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    monkeypatch.setenv("CAN_CHANNEL", channel)
    with MockArm("two-link-4-muscle", f"virtual:{channel}"):
        res = _collect(tmp_path / "m.parquet", "--robot", str(wrong), "--samples", 2,
                       port="default")
    assert res.exit_code == 1 and "m4 (board 5)" in res.output
    assert "describes the boards on this bus" in res.output and "Traceback" not in res.output
