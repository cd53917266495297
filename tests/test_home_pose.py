"""L_const (the home pose at zero tension) follows the training-set size in the default:
kept where a few rows leave the lengths near home unknown, left out where the rows carry
them and a loadcell zero that has moved would make the home pose contradict them."""

from __future__ import annotations

from pimbs_learn.io import load_body_schema
from pimbs_learn.losses import HOME_POSE_UP_TO, LossConfig, home_pose_kept, sized
from pimbs_learn.method_spec import parse_method


def test_the_rule_keeps_the_home_pose_at_few_samples_only() -> None:
    assert home_pose_kept(5) and home_pose_kept(10) and home_pose_kept(HOME_POSE_UP_TO)
    assert not home_pose_kept(HOME_POSE_UP_TO + 1) and not home_pose_kept(30)
    full = LossConfig.parse("basic+const+pinn", 1.0, "auto", sensors=True)
    assert sized(full, 10) == full
    assert sized(full, 30) == LossConfig.parse("basic+pinn", 1.0, "auto", sensors=True)
    m = parse_method("se:basic+const+pinn@auto~exp!check,sensors,home")
    assert m.loss_for(10).const and not m.loss_for(30).const and m.loss_for(30).pinn
    # without the flag a method is what it says at every size
    assert parse_method("se:basic+const+pinn@auto~exp!check,sensors").loss_for(30).const


def test_pimbs_train_leaves_the_home_pose_out_beyond_the_rule_and_says_so(tmp_path) -> None:
    from click.testing import CliRunner

    from pimbs_arm.model import ArmModel
    from pimbs_cli.train import command
    from pimbs_recording.format import write_recording
    from pimbs_sim.simulate import simulate

    data, meta = simulate(ArmModel.load("two-link-4-muscle"), 40, "atl", seed=0, noise=0.0)
    rec = tmp_path / "rec.parquet"
    write_recording(rec, data, meta)

    def trained(*args: str) -> tuple[str, str]:
        out = tmp_path / f"m{len(list(tmp_path.iterdir()))}"
        res = CliRunner().invoke(command, [str(rec), "--epochs", "3", "--hidden", "8",
                                           "--no-self-check", "--out", str(out), *args])
        assert res.exit_code == 0, res.output
        return load_body_schema(out).meta["metrics"]["loss"], res.output

    loss, said = trained("--n-train", "30", "--no-prior")
    assert loss == "basic+pinn"
    assert "L_const (the home pose at zero tension) left out at 30 training samples" in said
    assert "--loss basic+const+pinn keeps it" in said
    # kept: at 10 samples, when the loss is asked for, with a prior, with --paper
    for args in (("--n-train", "10", "--no-prior"),
                 ("--n-train", "30", "--no-prior", "--loss", "basic+const+pinn"),
                 ("--n-train", "30"), ("--n-train", "30", "--paper", "--hidden", "8")):
        loss, said = trained(*args)
        assert loss == "basic+const+pinn", args
        assert "left out" not in said, args
