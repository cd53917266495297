"""The straightforward trainer: the paper's method written the obvious way.

G = ∂h/∂θ by autograd, one backward pass per muscle with create_graph (so L_pinn's gradient
is a double backward), L_eval computed every epoch, plain (for-loop) Adam, one run at a time.
It is the yardstick for :mod:`pimbs_learn.train`: same model functions, same losses, same
initial weights and the same selection rule, so their results must agree.
"""

from __future__ import annotations

import time

import numpy as np
import torch

from pimbs_learn.data import LearnError
from pimbs_learn.losses import basic_loss, const_loss, pinn_loss
from pimbs_learn.model import BodySchemaNet, init_params
from pimbs_learn.run import Progress, Run, TrainOptions, TrainResult, as_tensor


def autograd_jacobian(l_pred: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
    """G (B, M, N) = ∂l/∂θ, one autograd pass per muscle, differentiable (create_graph)."""
    rows = [torch.autograd.grad(l_pred[:, m].sum(), theta, create_graph=True)[0]
            for m in range(l_pred.shape[1])]
    return torch.stack(rows, dim=1)


def train_reference(run: Run, options: TrainOptions | None = None,
                    progress: Progress | None = None, progress_every: int = 100
                    ) -> TrainResult:
    """Train one run the straightforward way; returns the same TrainResult as the fast one."""
    run.check()
    if run.structure != "mlp" or run.loss.weighting != "fixed":
        raise LearnError("the reference trainer implements the paper's method only (MLP "
                         "structure, fixed α); use the fast trainer")
    options = options or TrainOptions()
    dev, dt = options.torch_device(), options.dtype
    t0 = time.perf_counter()
    scaling = run.scaling()
    tr, ev = run.train, run.eval
    n, m = tr.theta.shape[1], tr.length.shape[1]
    net = BodySchemaNet(init_params(scaling.n_inputs, m, run.seed, options.hidden, dt),
                        scaling).to(dev)
    opt = torch.optim.Adam(net.parameters(), lr=options.lr, foreach=False)

    def t(a: np.ndarray) -> torch.Tensor:
        return as_tensor(a, dt, dev)

    th, f, l_data, tau = t(tr.theta), t(tr.tension), t(tr.length), t(np.nan_to_num(tr.tau))
    th_ev, f_ev, l_ev = t(ev.theta), t(ev.tension), t(ev.length)
    zero_th, zero_f = torch.zeros(1, n, dtype=dt, device=dev), torch.zeros(1, m, dtype=dt,
                                                                           device=dev)
    train_hist: list[float] = []
    eval_hist: list[float] = []
    best, best_state = float("inf"), None
    for epoch in range(options.epochs):
        theta = th.clone().requires_grad_(run.loss.pinn)
        l_pred = net(theta, f)
        lb = basic_loss(l_pred, l_data)
        total = lb
        if run.loss.const:
            total = total + const_loss(net(zero_th, zero_f)[0])
        if run.loss.pinn:
            g_t_f = torch.einsum("bmn,bm->bn", autograd_jacobian(l_pred, theta), f)
            total = total + run.loss.alpha * pinn_loss(g_t_f, tau)
        with torch.no_grad():
            train_hist.append(lb.item())
            eval_hist.append(basic_loss(net(th_ev, f_ev), l_ev).item())
            if train_hist[-1] < best:
                best = train_hist[-1]
                best_state = {k: v.detach().clone() for k, v in net.params.items()}
        opt.zero_grad()
        total.backward()
        for group in opt.param_groups:
            group["lr"] = options.lr_at(epoch)
        opt.step()
        if progress is not None and ((epoch + 1) % progress_every == 0
                                     or epoch + 1 == options.epochs):
            progress(epoch + 1)

    k = int(np.argmin(train_hist))  # first epoch with the lowest training L_basic
    assert best_state is not None
    every = max(options.curve_every, 1)
    return TrainResult(run=run, params={kk: v.cpu().float().numpy() for kk, v in
                                        best_state.items()},
                       scaling=scaling, best_epoch=k, train_loss=train_hist[k],
                       eval_loss=eval_hist[k], epochs=options.epochs, schedule=options.schedule,
                       seconds=time.perf_counter() - t0,
                       curve_epochs=np.arange(0, options.epochs, every),
                       curve_eval=np.asarray(eval_hist[::every]),
                       curve_train=np.asarray(train_hist[::every]))
