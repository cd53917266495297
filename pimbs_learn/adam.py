"""Adam for the fast trainer, without torch.optim.

Why not ``torch.optim.Adam``: constructing or stepping any ``torch.optim`` optimizer imports
``torch._dynamo`` (the compile machinery: sympy, torch.fx, …), which costs 1–2 s of start-up
on a 2-core CPU — more than a short training run itself. The fast trainer computes its
gradients by hand and needs none of that machinery, so it calls the very kernel that
``torch.optim.Adam(fused=True)`` calls, ``torch._fused_adam_`` (one pass over every tensor),
and keeps the optimizer state itself. Where a device or dtype has no fused kernel the same
update is written out with ``torch._foreach_*`` ops (the multi-tensor Adam's arithmetic).

The update is torch's Adam (no weight decay, no AMSGrad): bit for bit what
``torch.optim.Adam(params, lr, fused=True)`` does (checked by tests/test_adam.py).
"""

from __future__ import annotations

import torch


class FusedAdam:
    """Adam over a fixed list of tensors, stepped with explicit gradients.

    ``params`` are updated in place and need not require grad; ``step(grads, lr)`` takes
    the gradients in the same order. All state is allocated here, once, so a step allocates
    nothing (on the fused path).
    """

    def __init__(self, params: list[torch.Tensor], lr: float = 1e-3,
                 betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8) -> None:
        self.params = list(params)
        self.lr, (self.beta1, self.beta2), self.eps = lr, betas, eps
        self.exp_avg = [torch.zeros_like(p) for p in self.params]
        self.exp_avg_sq = [torch.zeros_like(p) for p in self.params]
        # torch keeps the step count as a float32 tensor beside each parameter (fused Adam)
        self.state_steps = [torch.zeros((), dtype=torch.float32, device=p.device)
                            for p in self.params]
        self.steps = 0
        self.fused = all(_has_fused_kernel(p) for p in self.params)

    def step(self, grads: list[torch.Tensor], lr: float | None = None) -> None:
        """One Adam update of every parameter with these gradients, at ``lr`` (or the
        constructor's)."""
        lr = self.lr if lr is None else lr
        self.steps += 1
        torch._foreach_add_(self.state_steps, 1)
        if self.fused:
            torch._fused_adam_(self.params, grads, self.exp_avg, self.exp_avg_sq, [],
                               self.state_steps, lr=lr, beta1=self.beta1, beta2=self.beta2,
                               weight_decay=0.0, eps=self.eps, amsgrad=False, maximize=False)
        else:
            self._foreach_step(grads, lr)

    def _foreach_step(self, grads: list[torch.Tensor], lr: float) -> None:
        """The multi-tensor Adam's arithmetic (torch.optim.adam._multi_tensor_adam)."""
        b1, b2, k = self.beta1, self.beta2, self.steps
        torch._foreach_lerp_(self.exp_avg, grads, 1 - b1)
        torch._foreach_mul_(self.exp_avg_sq, b2)
        torch._foreach_addcmul_(self.exp_avg_sq, grads, grads, 1 - b2)
        bias1 = 1 - b1 ** k
        bias2_sqrt = (1 - b2 ** k) ** 0.5
        denom = torch._foreach_sqrt(self.exp_avg_sq)
        torch._foreach_div_(denom, bias2_sqrt)
        torch._foreach_add_(denom, self.eps)
        torch._foreach_addcdiv_(self.params, self.exp_avg, denom, -lr / bias1)


def _has_fused_kernel(like: torch.Tensor) -> bool:
    """Whether ``torch._fused_adam_`` runs for tensors of this device and dtype (tried on a
    scratch tensor, so a refusal never leaves a real parameter half updated)."""
    one = [torch.zeros(1, dtype=like.dtype, device=like.device)]
    try:
        torch._fused_adam_([one[0].clone()], [one[0].clone()], [one[0].clone()],
                           [one[0].clone()], [],
                           [torch.ones((), dtype=torch.float32, device=like.device)],
                           lr=1e-3, beta1=0.9, beta2=0.999, weight_decay=0.0, eps=1e-8,
                           amsgrad=False, maximize=False)
    except (RuntimeError, NotImplementedError, AttributeError):
        return False
    return True
