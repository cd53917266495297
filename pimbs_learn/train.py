"""The fast trainer: R runs (seeds × losses × α) trained at once on stacked weights.

Why it is fast, compared with :mod:`pimbs_learn.reference`:
- Gᵀf comes from the analytic chain rule (:func:`model.gtf`), and the whole gradient of
  L_train is written out by hand (:mod:`pimbs_learn.objective`): no autograd graph, no
  double backward, the two W2 weight-gradient products fused into one matmul. What is left
  is ~5 matmuls with the 1000×1000 layer per epoch, which is the cost floor on a CPU.
- L_const rides along as one extra all-zero row of the training batch.
- Fused Adam (one kernel over every tensor) where torch has it, called without
  torch.optim (:mod:`pimbs_learn.adam`), whose import of the compile machinery costs more
  start-up than a short run.
- No evaluation during training: the weights of each new best epoch are kept (copied on
  the CPU; a masked copy without host sync on a GPU) and L_eval is computed once, for those
  weights, at the end — exactly the selection rule's number, with one evaluation.
- Runs can be stacked along a leading axis (batched matmuls), so on a GPU a whole table of
  runs costs about as much as one; Adam is element-wise, so stacked runs stay independent.
"""

from __future__ import annotations

import time

import numpy as np
import torch

from pimbs_learn import sensor_terms
from pimbs_learn.adam import FusedAdam
from pimbs_learn.data import LearnError
from pimbs_learn.graph import ELASTIC_BASIS, SERIES_ELASTIC, elastic_basis
from pimbs_learn.model import Params, hidden_layers, init_params, output_length
from pimbs_learn.noise import noise_of
from pimbs_learn.objective import ELASTIC_GAIN, Batch, elastic_length, objective_and_grads
from pimbs_learn.prior import PREFIX as PRIOR_PREFIX
from pimbs_learn.run import Progress, Run, TrainOptions, TrainResult, as_tensor

_EVAL_CHUNK = 2048  # eval rows per matmul; bounds memory for large evaluation sets
# Floors of the profiled variances (automatic physics weight), relative to the training
# data's own scales: rms length error ≥ LENGTH_FLOOR·max|l|, rms torque error ≥
# TORQUE_FLOOR·max|τ|, and the torque floor is raised to the evidence's torque noise
# (:func:`_torque_floor`). They matter once the network fits its samples that well.
LENGTH_FLOOR = 1e-4
TORQUE_FLOOR = 1e-3


def _torque_floor(r: Run, auto: bool) -> tuple[float, float | None]:
    """(floor of mse_τ, the evidence's torque noise rms or None) of one run.

    With the automatic weight the floor is also the torque noise that a smooth model of
    lengths and torques together supports (:mod:`pimbs_learn.noise`): the network can
    interpolate wrong torques, the evidence cannot be fooled that way, so where the torque
    balance is off (friction, offsets) the physics weight backs off by itself.
    """
    floor = (TORQUE_FLOOR * float(np.nan_to_num(np.abs(r.train.tau)).max() + 1e-12)) ** 2
    if not auto:
        return floor, None
    noise = (_evidence_noise(r.train, r.seed, r.loss.sensors) if r.torque_noise is None
             else r.torque_noise)
    if not np.isfinite(noise):  # a degenerate sample set: keep the relative floor
        return floor, None
    return max(floor, noise ** 2), noise


def torque_noise(run: Run) -> float:
    """The torque noise (N·m rms) the evidence of ``run``'s training rows supports
    (:mod:`pimbs_learn.noise`; with a prior, of the residual the network learns), or NaN
    where the sample set is degenerate."""
    return _evidence_noise(run.residual().train, run.seed, run.loss.sensors)


def _evidence_noise(t, seed: int, sensors: bool = False) -> float:
    e = noise_of(t, seed, sensors)
    return float("nan") if e is None else e.torque_rms


def _stack(arrays: list[np.ndarray], dtype: torch.dtype, dev: torch.device) -> torch.Tensor:
    return as_tensor(np.stack(arrays), dtype, dev)


def _check_stackable(runs: list[Run]) -> None:
    """Runs train together when their tensors stack: the same numbers of training samples,
    joints and muscles, the same map and structure. Names do not matter (arms of one shape
    stack, whatever their joints are called), nor do evaluation sizes (padded and masked)."""
    if not runs:
        raise LearnError("no runs to train")
    first = runs[0]

    def shape(r: Run) -> tuple:
        return (r.train.n_samples, r.atl, len(r.train.joints), len(r.train.muscles),
                r.structure)

    for r in runs:
        r.check()
        if shape(r) != shape(first):
            raise LearnError("runs trained together need the same n_train, map, structure and "
                             "numbers of joints and muscles; train the others in a separate "
                             "batch")


def _padded(arrays: list[np.ndarray]) -> np.ndarray:
    """Stack row arrays of different lengths, zero-padded to the longest."""
    rows = max(len(a) for a in arrays)
    out = np.zeros((len(arrays), rows) + arrays[0].shape[1:], dtype=np.float64)
    for i, a in enumerate(arrays):
        out[i, :len(a)] = a
    return out


def _eval_loss(p: Params, x: torch.Tensor, phi: torch.Tensor | None, l_data: torch.Tensor,
               ls: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """L_eval per run, evaluated in row chunks: the sum of chunk SSEs over each run's own
    rows (``mask`` (R, S, 1): 1 on a run's rows, 0 on the padding) / (rows · muscles)."""
    sse = torch.zeros(x.shape[0], dtype=x.dtype, device=x.device)
    for i in range(0, x.shape[1], _EVAL_CHUNK):
        _, a2 = hidden_layers(p, x[:, i:i + _EVAL_CHUNK])
        ph = None if phi is None else phi[:, i:i + _EVAL_CHUNK]
        d = (output_length(p, a2, ls) + elastic_length(p, ph, ls)
             - l_data[:, i:i + _EVAL_CHUNK]) * mask[:, i:i + _EVAL_CHUNK]
        sse += (d * d).sum(dim=(-2, -1))
    return sse / (mask.sum(dim=(-2, -1)) * l_data.shape[2])


def _keep_best(p: Params, best_p: Params, improved: torch.Tensor, on_host: bool) -> None:
    """Copy the weights of runs whose training L_basic just improved into best_p.

    On the CPU reading the flags costs nothing, and copying only improved runs is ~10x
    cheaper than a masked select over every weight; on a GPU the masked select avoids a
    host sync per epoch.
    """
    if on_host:
        for i in torch.nonzero(improved).flatten().tolist():
            for k, v in p.items():
                best_p[k][i].copy_(v[i])
    else:
        for k, v in p.items():
            torch.where(improved.view(-1, 1, 1), v, best_p[k], out=best_p[k])


def train_runs(runs: list[Run], options: TrainOptions | None = None,
               progress: Progress | None = None, progress_every: int = 100
               ) -> list[TrainResult]:
    """Train all runs together; each gets its own init (its seed), data, loss and α."""
    _check_stackable(runs)
    given, runs = runs, [r.residual() for r in runs]
    options = options or TrainOptions()
    dev, dt = options.torch_device(), options.dtype
    t0 = time.perf_counter()
    r_n = len(runs)
    n = runs[0].train.theta.shape[1]
    scalings = [r.scaling() for r in runs]

    elastic = runs[0].structure == SERIES_ELASTIC
    with_f = runs[0].network_inputs_tension
    inv = _stack([s.input_inverse()[None] for s in scalings], dt, dev)  # (R,1,D)
    if not with_f:
        inv = inv[..., :n]
    ls = _stack([s.length[None] for s in scalings], dt, dev)  # (R,1,M)
    th_inv = inv[..., :n]

    def inputs(samples_of: str) -> torch.Tensor:
        xs = []
        for r in runs:
            s = getattr(r, samples_of)
            xs.append(np.hstack([s.theta, s.tension]) if with_f else s.theta)
        return as_tensor(_padded(xs), dt, dev) * inv

    def basis(samples_of: str) -> torch.Tensor | None:
        if not elastic:
            return None
        f = as_tensor(_padded([getattr(r, samples_of).tension for r in runs]), dt, dev)
        fs = _stack([s.tension[None] for s in scalings], dt, dev)  # type: ignore[index]
        return elastic_basis(f, fs)

    x_tr = inputs("train")
    phi_tr = basis("train")
    is_auto = [r.loss.pinn and r.loss.weighting == "auto" for r in runs]
    floors = [_torque_floor(r, a) for r, a in zip(runs, is_auto, strict=True)]
    batch = Batch(
        x=torch.cat([x_tr, torch.zeros_like(x_tr[:, :1])], dim=1),  # row B: h(0, 0)
        length=_stack([r.train.length for r in runs], dt, dev),
        tension=_stack([r.train.tension for r in runs], dt, dev),
        tau=_stack([np.nan_to_num(r.train.tau) for r in runs], dt, dev),
        length_scale=ls, theta_inverse=th_inv,
        const_weight=torch.tensor([r.loss.const_weight for r in runs], dtype=dt, device=dev),
        pinn_weight=torch.tensor([r.loss.pinn_weight for r in runs], dtype=dt, device=dev),
        phi=None if phi_tr is None else torch.cat([phi_tr, torch.zeros_like(phi_tr[:, :1])],
                                                  dim=1),
        auto=torch.tensor(is_auto, dtype=dt, device=dev),
        length_floor=torch.tensor([(LENGTH_FLOOR * float(np.abs(r.train.length).max())) ** 2
                                   for r in runs], dtype=dt, device=dev),
        torque_floor=torch.tensor([f for f, _ in floors], dtype=dt, device=dev),
        sensors=torch.tensor([r.loss.sensors for r in runs], dtype=dt, device=dev),
        tension_scale=_stack([s.tension[None] if s.tension is not None
                              else np.ones((1, len(r.train.muscles)))
                              for s, r in zip(scalings, runs, strict=True)], dt, dev))
    x_ev = inputs("eval")
    phi_ev = basis("eval")
    l_ev = as_tensor(_padded([r.eval.length for r in runs]), dt, dev)
    mask_ev = as_tensor(_padded([np.ones((r.eval.n_samples, 1)) for r in runs]), dt, dev)

    m = batch.length.shape[-1]
    inits = [init_params(x_tr.shape[-1], m, r.seed, options.hidden, dt) for r in runs]
    for r, i in zip(runs, inits, strict=True):
        if elastic:  # linear in c: starting at zero breaks no symmetry
            i["c"] = torch.zeros(len(ELASTIC_BASIS), m, dtype=dt)
        if r.prior is not None:  # start exactly at the geometric model
            i["w3"].zero_()
            i["b3"].zero_()
    p: Params = {k: torch.stack([i[k] for i in inits]).to(dev) for k in inits[0]}
    if batch.use_sensors:
        p.update({k: v.to(dev) for k, v in sensor_terms.zeros(r_n, m, n, dt).items()})
    opt = FusedAdam(list(p.values()), options.lr)
    best_p = {k: v.detach().clone() for k, v in p.items()}
    best = torch.full((r_n,), float("inf"), dtype=dt, device=dev)  # selection score
    best_lb = torch.full((r_n,), float("inf"), dtype=dt, device=dev)
    best_epoch = torch.zeros(r_n, dtype=torch.long, device=dev)
    on_host = dev.type == "cpu"
    curve_e: list[int] = []
    curve_v: list[torch.Tensor] = []
    curve_t: list[torch.Tensor] = []

    for epoch in range(options.epochs):
        with torch.no_grad():
            lb, grads, score = objective_and_grads(p, batch)
            improved = score < best
            best = torch.where(improved, score, best)
            best_lb = torch.where(improved, lb, best_lb)
            best_epoch = torch.where(improved, epoch, best_epoch)
            _keep_best(p, best_p, improved, on_host)
            if options.curve_every and epoch % options.curve_every == 0:
                curve_e.append(epoch)
                curve_v.append(_eval_loss(p, x_ev, phi_ev, l_ev, ls, mask_ev))
                curve_t.append(lb)
        opt.step([grads[k] for k in p], options.lr_at(epoch))
        if progress is not None and ((epoch + 1) % progress_every == 0
                                     or epoch + 1 == options.epochs):
            progress(epoch + 1)

    with torch.no_grad():
        ev = _eval_loss(best_p, x_ev, phi_ev, l_ev, ls, mask_ev).cpu().numpy()
        curve = torch.stack(curve_v).cpu().numpy() if curve_v else np.zeros((0, r_n))
        curve_tr = torch.stack(curve_t).cpu().numpy() if curve_t else np.zeros((0, r_n))
    seconds = time.perf_counter() - t0
    best_np, epoch_np = best_lb.cpu().numpy(), best_epoch.cpu().numpy()
    weights = {k: v.cpu().float().numpy() for k, v in best_p.items()}

    def params_of(i: int, r: Run) -> dict[str, np.ndarray]:
        out = {k: w[i] for k, w in weights.items() if k not in sensor_terms.KEYS}
        if "c" in out:
            out["c"] = out["c"] * np.float32(ELASTIC_GAIN)
        if r.prior is not None:
            out.update({PRIOR_PREFIX + k: v for k, v in r.prior.items()})
        return out

    return [TrainResult(run=r, params=params_of(i, r),
                        scaling=scalings[i], best_epoch=int(epoch_np[i]),
                        train_loss=float(best_np[i]), eval_loss=float(ev[i]),
                        epochs=options.epochs, seconds=seconds, schedule=options.schedule,
                        torque_noise_rms=floors[i][1],
                        sensor_terms=sensor_terms.physical(
                            {k: weights[k][i] for k in sensor_terms.KEYS},
                            scalings[i].tension) if r.loss.sensors else None,
                        curve_epochs=np.asarray(curve_e, int), curve_eval=curve[:, i],
                        curve_train=curve_tr[:, i])
            for i, r in enumerate(given)]


def train(run: Run, options: TrainOptions | None = None,
          progress: Progress | None = None) -> TrainResult:
    """Train one run (see :func:`train_runs`); with ``options.members`` > 1 as that many
    networks from different initial weights, stacked, merged into one
    (:mod:`pimbs_learn.ensemble`)."""
    if options is not None and options.members > 1:
        from pimbs_learn.ensemble import member_runs, merge

        return merge(train_runs(member_runs(run, options.members), options, progress))
    return train_runs([run], options, progress)[0]
