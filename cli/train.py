"""`pimbs train`: learn a body schema (AL- or ATL-Map) from one recording."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import click

from pimbs_cli.common import check_output, force_option, progress, user_errors
from pimbs_learn.widths import DEFAULT_HIDDEN, HIDDEN

LOSSES = ["basic", "basic+const", "basic+pinn", "basic+const+pinn"]
DEFAULT_LOSS = "basic+const+pinn"
DEFAULT_PAPER_ALPHA = 1e-5  # the paper's α (fixed weight, physical units)
# Evaluation samples whose joint angles are estimated after training (a seeded draw): the
# summary's cost stays bounded however large the evaluation set (`pimbs estimate` does all).
JOINT_ANGLE_ROWS = 64


@click.command("train")
@click.argument("data", type=click.Path(path_type=Path))
@click.option("--map", "map_kind", type=click.Choice(["atl", "al"]), default="atl",
              show_default=True, help="atl: (θ, f) → l; al: θ → l")
@click.option("--loss", type=click.Choice(LOSSES), default=DEFAULT_LOSS, show_default=True,
              help="the paper's terms: length error (basic), h(0, 0) = 0 (const), the torque "
                   "balance -Gᵀf = τ (pinn); the default leaves const out beyond 20 "
                   "training samples where no prior is used (give --loss to keep it)")
@click.option("--structure", type=click.Choice(["series-elastic", "mlp"]),
              default="series-elastic", show_default=True,
              help="series-elastic: l = g(θ) + e(f) (ATL-Map); mlp: the paper's network")
@click.option("--alpha", type=click.FloatRange(min=0), default=None,
              help="fixed weight α of L_pinn in physical units, as in the paper (e.g. 1e-7) "
                   "[default: automatic, from the residuals' own scales]")
@click.option("--weighting", type=click.Choice(["auto", "fixed"]), default=None,
              help="auto: α balanced every epoch by profiled likelihood (with --alpha: a "
                   "multiplier of it); fixed: --alpha as is [default: auto unless --alpha]")
@click.option("--prior/--no-prior", default=True, show_default=True,
              help="start from the robot description's model (the recording's robot or "
                   "--robot) and learn its correction; skipped with a note if unavailable")
@click.option("--n-train", type=click.IntRange(min=1), default=None,
              help="train on N rows drawn with --seed; evaluate on the rest (or on --eval) "
                   "[default: 80 % of the rows, drawn with --seed; the output names the "
                   "rows that evaluate]")
@click.option("--eval", "eval_path", type=click.Path(path_type=Path), default=None,
              help="evaluate on this recording (same joints and muscles)")
@click.option("--epochs", type=click.IntRange(min=1), default=20000, show_default=True,
              help="full-batch training epochs (the paper's 20000)")
@click.option("--seed", type=int, default=0, show_default=True,
              help="seeds the training draw and the initial weights")
@click.option("--lr", type=click.FloatRange(min=0, min_open=True), default=1e-3,
              show_default=True, help="Adam learning rate (of the first epoch)")
@click.option("--lr-schedule", "schedule", type=click.Choice(["exp", "constant", "cosine"]),
              default="exp", show_default=True,
              help="exp: lr decays to 1 % of --lr over the run; constant: the paper's Adam")
@click.option("--hidden", type=click.IntRange(min=1), default=DEFAULT_HIDDEN, show_default=True,
              help="width of the two hidden layers (the paper's: 1000)")
@click.option("--self-check/--no-self-check", "check", default=True, show_default=True,
              help="train without the physics terms where the training rows do not show "
                   "that the recorded torques help predict lengths at poses left out "
                   "(each sample predicted from the others, with and without torques)")
@click.option("--sensor-terms/--no-sensor-terms", "sensors", default=None,
              help="fit a gain and an offset per loadcell and a gravity scale per joint "
                   "inside the torque balance (each held near none by a prior), so a "
                   "consistent sensor error does not bend the body schema [default: on where "
                   "the balance can carry them: the pinn loss with the automatic weight on "
                   "an ATL-Map without a prior]")
@click.option("--members", type=click.IntRange(min=1), default=None,
              help="train the asked network and K − 1 more on the same rows from other "
                   "initial weights, and keep their mean, stored as one wider network: from "
                   "8 training samples on the others leave out L_const (the home pose), with "
                   "7 or fewer they are Basic [default: 2 with at most 20 training samples, "
                   "where the rows cannot tell whether the physics holds; else 1]")
@click.option("--paper", is_flag=True,
              help="the paper's configuration: --structure mlp --no-prior --alpha 1e-5 "
                   "--lr-schedule constant --hidden 1000 --no-self-check --members 1 (options "
                   "given explicitly still apply)")
@click.option("--robot", default=None,
              help="robot NAME|PATH: the prior, and τ where the recording's tau_gravity is "
                   "null [default: the recording's robot]")
@click.option("--device", type=click.Choice(["cpu", "cuda"]), default="cpu", show_default=True,
              help="where torch trains (cuda needs a CUDA build of torch)")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="directory to write the model (model.safetensors + model.json); "
                   "without it nothing but the metrics is kept")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, path_type=Path),
              default=None, help="write the metrics here")
@click.option("--reference", is_flag=True,
              help="use the straightforward (slow) trainer instead of the fast one")
@click.option("--threads", type=click.IntRange(min=1), default=None,
              help="CPU threads for torch [default: torch's]; 1 is fastest on a busy machine")
@force_option()
@click.pass_context
@user_errors
def command(ctx: click.Context, threads: int | None, data: Path, map_kind: str, loss: str,
            structure: str, alpha: float | None, weighting: str | None, prior: bool,
            n_train: int | None, eval_path: Path | None, epochs: int, seed: int, lr: float,
            schedule: str, hidden: int, check: bool, sensors: bool, members: int | None,
            paper: bool, robot: str | None,
            device: str, out: Path | None, json_path: Path | None, reference: bool,
            force: bool) -> None:
    """Learn h(θ[, f]) → l from DATA (a recording).

    Default: the series-elastic ATL-Map on top of the robot description's model (when the
    recording's robot or --robot loads), with the physics terms weighted automatically and
    a decaying learning rate. `--structure mlp --no-prior --alpha 1e-5 --lr-schedule
    constant` is the paper's method, which keeps the epoch with the lowest training L_basic
    (the default: the lowest profiled likelihood of lengths and torques); the L_eval of the
    epoch kept (mean over samples and muscles of squared length error, m², ×1e5) is the
    result.
    """
    if paper:
        given = {name for name in ctx.params
                 if ctx.get_parameter_source(name) != click.core.ParameterSource.DEFAULT}
        paper_values = {"structure": "mlp", "prior": False, "alpha": DEFAULT_PAPER_ALPHA,
                        "schedule": "constant", "hidden": HIDDEN, "check": False,
                        "sensors": False, "members": 1}
        values = {k: v for k, v in paper_values.items() if k not in given}
        structure = values.get("structure", structure)
        prior = values.get("prior", prior)
        alpha = values.get("alpha", alpha)
        schedule = values.get("schedule", schedule)
        hidden = values.get("hidden", hidden)
        check = values.get("check", check)
        sensors = values.get("sensors", sensors)
        members = values.get("members", members)
    # refuse an output that exists or cannot be written before minutes of training
    if out is not None and not (out.is_dir() and not any(out.iterdir())):  # empty dir: ok
        check_output(out, force=force, what="model")
    if json_path is not None:
        check_output(json_path, force=force, what="file", option="--json")
    import torch
    from rich.console import Console

    from pimbs_learn.ensemble import members_for
    from pimbs_learn.io import save_model
    from pimbs_learn.losses import DEFAULT_ALPHA, HOME_POSE_UP_TO, LossConfig, sized
    from pimbs_learn.reference import train_reference
    from pimbs_learn.run import TrainOptions
    from pimbs_learn.selfcheck import applies, train_checked
    from pimbs_learn.session import model_error, prepare_run
    from pimbs_learn.train import train
    from pimbs_recording.atomic import write_text_atomic

    if threads:
        torch.set_num_threads(threads)
    console = Console(stderr=True, soft_wrap=True)  # a log gets whole lines, not wrapped
    weighting = weighting or ("fixed" if alpha is not None else "auto")
    if alpha is None:
        alpha = 1.0 if weighting == "auto" else DEFAULT_ALPHA
    if sensors and not (weighting == "auto" and "pinn" in loss.split("+")):
        raise click.UsageError("--sensor-terms fit errors inside the torque balance: they "
                               "need the pinn loss with the automatic weight (no --alpha)")
    run = prepare_run(data, LossConfig.parse(loss, alpha, weighting, bool(sensors)),
                      atl=map_kind == "atl",
                      n_train=n_train, eval_path=eval_path, seed=seed, robot=robot,
                      structure=structure, prior=prior and not reference,
                      note=lambda s: console.print(f"note: {s}", markup=False))
    if sensors is None and run.sensor_terms_apply:
        run = replace(run, loss=replace(run.loss, sensors=True))
    loss_given = ctx.get_parameter_source("loss") != click.core.ParameterSource.DEFAULT
    if not (loss_given or paper or reference or run.prior is not None):
        home = sized(run.loss, run.train.n_samples)
        if home != run.loss:
            run = replace(run, loss=home)
            console.print(f"note: L_const (the home pose at zero tension) left out at "
                          f"{run.train.n_samples} training samples (kept up to "
                          f"{HOME_POSE_UP_TO}): the rows carry the lengths near home, and a "
                          f"loadcell zero that has moved would make the home pose contradict "
                          f"them; --loss {loss} keeps it", markup=False)
    torch.manual_seed(seed)
    if reference and (members or 1) > 1:
        raise click.UsageError("--reference trains one network: leave out --members")
    if members is None:
        members = 1 if reference else members_for(run.train.n_samples)
    options = TrainOptions(epochs=epochs, lr=lr, device=device, hidden=hidden,
                           schedule=schedule, members=members)
    checked = check and not reference and applies(run)
    trainer = train_reference if reference else (train_checked if checked else train)
    weight = (f"automatic α ×{alpha:g}" if weighting == "auto" else f"α={alpha:g}")
    if run.loss.sensors:
        weight += ", sensor terms"
    console.print(f"{map_kind.upper()}-Map ({run.structure}"
                  f"{f', prior {run.prior_robot}' if run.prior_robot else ''}), {run.loss.name}"
                  f"{f' ({weight})' if run.loss.pinn else ''}: {run.train.n_samples} "
                  f"training / {run.eval.n_samples} evaluation samples, "
                  f"{len(run.train.joints)} joints, {len(run.train.muscles)} muscles")
    if out is None:
        console.print("note: no --out, so the model will not be saved (only the metrics "
                      "are printed); stop now and add --out DIR to keep it", markup=False)
    with progress("training", epochs, "epochs", console=console) as update:
        result = trainer(run, options, progress=update)
    if result.self_check is not None:
        console.print(result.self_check.line(run.loss.name), markup=False)
    if result.members is not None:
        nets = result.metrics()["members"]
        each = ", ".join(f"{m['eval_loss']:.4g}" for m in nets)
        losses = " and ".join(m["loss"] for m in nets)
        console.print(f"{len(result.members)} networks averaged into one ({losses}, each from "
                      f"its own initial weights; L_eval each: {each})", markup=False)
    if result.sensor_terms is not None:
        from pimbs_learn.sensor_terms import line

        console.print(line(result.sensor_terms, list(run.train.muscles),
                           list(run.train.joints)), markup=False)

    metrics = result.metrics()
    metrics.update(data=str(data), data_sha256=run.train.sha256,
                   eval_data=str(eval_path) if eval_path else None,
                   trainer="reference" if reference else "fast", device=device,
                   eval_rms_mm=1e3 * (result.eval_loss ** 0.5))
    console.print(f"best epoch {result.best_epoch}/{epochs}: train L_basic "
                  f"{metrics['train_loss']:.4g}, eval L_eval {metrics['eval_loss']:.4g} "
                  f"(×1e5 m², rms {metrics['eval_rms_mm']:.3f} mm) in {result.seconds:.1f} s")
    if result.torque_noise_rms is not None:
        console.print(f"torque balance known to ±{result.torque_noise_rms:.3g} N·m rms (evidence "
                      "of lengths and torques together); the physics weight floors there",
                      markup=False)
    geo = model_error(run)
    if geo is not None:
        metrics.update(model_eval_loss=geo["eval_loss"], model_rms_mm=geo["rms_mm"])
        console.print(f"the robot description's model alone ({run.prior_robot}): L_eval "
                      f"{geo['eval_loss']:.4g} (rms {geo['rms_mm']:.3f} mm) on the same "
                      "evaluation samples")
    angles = _joint_angles(result, robot)
    n_angles = len(angles.theta)
    metrics.update(eval_joint_angle_rms_deg=angles.rms_error_deg.tolist(),
                   eval_joint_angle_rows=n_angles,
                   eval_joint_angle_rms_deg_geometric=None
                   if angles.geometric_rms_error_deg is None
                   else angles.geometric_rms_error_deg.tolist())
    console.print(f"joint angles estimated from the lengths and tensions of {n_angles} of "
                  f"{result.run.eval.n_samples} evaluation samples, rms: {angles.line()}")
    if out is not None:
        save_model(result, out)
        console.print(f"model written to {out}/")
    else:
        console.print("model not saved (no --out)")
    if json_path is not None:
        write_text_atomic(json_path, json.dumps(metrics, indent=2) + "\n")
    click.echo(json.dumps({k: metrics[k] for k in ("eval_loss", "train_loss", "best_epoch",
                                                   "epochs", "seconds", "eval_rms_mm",
                                                   "model_rms_mm", "eval_joint_angle_rms_deg")
                           if k in metrics}))


def _joint_angles(result, robot: str | None):
    """Joint-angle error on the evaluation samples (degrees: what a roboticist reads)."""
    from pimbs_learn.estimate import joint_angle_report
    from pimbs_learn.io import schema_from_result

    ev = result.run.eval
    return joint_angle_report(schema_from_result(result), ev.theta, ev.tension, ev.length,
                              robot=robot or ev.robot, max_rows=JOINT_ANGLE_ROWS)
