"""The fast trainer's Adam: torch.optim.Adam's update exactly, without its import cost."""

from __future__ import annotations

import subprocess
import sys

import pytest
import torch

from pimbs_learn.adam import FusedAdam


def _tensors(dtype: torch.dtype) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(3)
    return [torch.randn(7, 5, generator=g, dtype=dtype), torch.randn(1, 5, generator=g,
                                                                     dtype=dtype)]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("fused", [True, False])
def test_same_update_as_torch_adam(dtype: torch.dtype, fused: bool) -> None:
    """Five steps with changing gradients and learning rates (the trainer's decaying
    schedule): the fused path is bit for bit torch's fused Adam, the fallback matches to
    rounding."""
    torch.set_num_threads(1)
    ours = [t.clone() for t in _tensors(dtype)]
    theirs = [t.clone().requires_grad_(True) for t in _tensors(dtype)]
    adam = FusedAdam(ours, lr=1e-2)
    adam.fused = adam.fused and fused
    assert adam.fused == fused  # this torch has the CPU kernel
    opt = torch.optim.Adam(theirs, lr=1e-2, fused=True)
    g = torch.Generator().manual_seed(4)
    for k in range(5):
        grads = [torch.randn(t.shape, generator=g, dtype=dtype) for t in ours]
        lr = 1e-2 * 0.7 ** k
        adam.step(grads, lr)
        for t, gr in zip(theirs, grads, strict=True):
            t.grad = gr.clone()
        opt.param_groups[0]["lr"] = lr
        opt.step()
    for a, b in zip(ours, theirs, strict=True):
        if fused:
            assert torch.equal(a, b.detach())
        else:
            torch.testing.assert_close(a, b.detach(), rtol=1e-6 if dtype == torch.float32
                                       else 1e-12, atol=0)
    assert not any(t.requires_grad for t in ours)


def test_no_compile_machinery_imported() -> None:
    """Building and stepping it does not import torch._dynamo (seconds of start-up)."""
    code = ("import sys, torch\n"
            "from pimbs_learn.adam import FusedAdam\n"
            "p = [torch.zeros(3)]\n"
            "a = FusedAdam(p)\n"
            "a.step([torch.ones(3)])\n"
            "assert float(p[0][0]) < 0\n"
            "print('torch._dynamo' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"
