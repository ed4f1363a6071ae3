"""Adam for inference's small fits, without ``torch.optim``.

Constructing any ``torch.optim`` optimiser imports ``torch._dynamo`` (the compiler stack): on a
busy 2-core host that cost 10-16 s in a fresh process, which a one-scene ``cnfmp predict``
would pay to fit a handful of simplex weights. This is torch's own single-tensor Adam update
(its CPU default: betas 0.9 / 0.999, eps 1e-8, no weight decay, no amsgrad), step for step, so
a fit gives the same numbers as with ``torch.optim.Adam``. Training keeps ``torch.optim``.
"""

from __future__ import annotations

import torch


class Adam:
    """Adam on one tensor that requires grad: ``zero_grad()``, backward, ``step()``."""

    def __init__(self, param: torch.Tensor, lr: float, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8):
        self.param, self.lr, self.betas, self.eps = param, lr, betas, eps
        self.exp_avg = torch.zeros_like(param, memory_format=torch.preserve_format)
        self.exp_avg_sq = torch.zeros_like(param, memory_format=torch.preserve_format)
        self.steps = 0

    def zero_grad(self) -> None:
        self.param.grad = None

    @torch.no_grad()
    def step(self) -> None:
        """One update from ``param.grad`` (in the order torch's ``_single_tensor_adam`` runs it)."""
        grad, (beta1, beta2) = self.param.grad, self.betas
        self.steps += 1
        self.exp_avg.lerp_(grad, 1 - beta1)
        self.exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
        bias_correction1 = 1 - beta1 ** self.steps
        bias_correction2_sqrt = (1 - beta2 ** self.steps) ** 0.5
        denom = (self.exp_avg_sq.sqrt() / bias_correction2_sqrt).add_(self.eps)
        self.param.addcdiv_(self.exp_avg, denom, value=-(self.lr / bias_correction1))
