"""A training method written as one word, for research drivers that compare many of them.

``STRUCTURE:LOSS[@WEIGHT][~SCHEDULE][!FLAG[,FLAG]]``: the structure (``mlp``, the paper's
network, or ``se``, series-elastic), the loss terms (``basic``, ``basic+const``, ``basic+pinn``,
``basic+const+pinn``), the physics weight (a number, α of the paper, default 1e-5; or
``auto``, optionally ``autoX``/``autoxX`` to scale the automatic weight by X) and the
learning-rate schedule (default ``constant``, the paper's Adam); the flag ``check`` runs the
self-check first (:mod:`pimbs_learn.selfcheck`), which may replace the loss by Basic, and
``sensors`` fits loadcell and gravity errors in the torque balance
(:mod:`pimbs_learn.sensor_terms`), ``members`` averages as many networks as
``pimbs train`` does for the run's training-set size (:mod:`pimbs_learn.ensemble`), and
``home`` keeps L_const only up to the training-set size the default keeps it
(:func:`pimbs_learn.losses.sized`).
Examples: ``se:basic+const+pinn@auto~exp!check`` (the default of ``pimbs train`` without a
prior), ``se:basic+const+pinn@auto~exp`` (the same without its self-check),
``se:basic~exp`` (Basic with that structure and schedule), ``mlp:basic`` (the paper's Basic).
"""

from __future__ import annotations

from dataclasses import dataclass

from pimbs_learn.graph import MLP, SERIES_ELASTIC
from pimbs_learn.losses import LossConfig, sized
from pimbs_learn.run import SCHEDULES

STRUCTURE_NAMES = {"mlp": MLP, "se": SERIES_ELASTIC}


@dataclass(frozen=True)
class Method:
    """A parsed method: its text, network structure, loss and learning-rate schedule."""

    spec: str
    structure: str
    loss: LossConfig
    schedule: str
    check: bool = False  # the self-check decides between this loss and Basic
    members: bool = False  # networks averaged by the training-set size rule
    home: bool = False  # L_const by the training-set size rule

    def loss_for(self, n_train: int) -> LossConfig:
        """The loss a run of ``n_train`` training samples trains with."""
        return sized(self.loss, n_train) if self.home else self.loss


def parse_method(spec: str) -> Method:
    """Parse ``STRUCTURE:LOSS[@WEIGHT][~SCHEDULE][!FLAG[,FLAG]]``; ``ValueError`` naming
    what is wrong."""
    text, _, flag_text = spec.partition("!")
    flags = set(flag_text.split(",")) - {""}
    if flags - {"check", "sensors", "members", "home"}:
        raise ValueError(f"method '{spec}': flags are 'check', 'sensors', 'members' and "
                         f"'home', not '{flag_text}'")
    body, _, schedule = text.partition("~")
    short, _, rest = body.partition(":")
    loss, _, weight = rest.partition("@")
    if short not in STRUCTURE_NAMES:
        raise ValueError(f"method '{spec}': structure '{short}' is not one of "
                         f"{', '.join(STRUCTURE_NAMES)}")
    schedule = schedule or "constant"
    if schedule not in SCHEDULES:
        raise ValueError(f"method '{spec}': schedule '{schedule}' is not one of "
                         f"{', '.join(SCHEDULES)}")
    sensors = "sensors" in flags
    try:
        if weight.startswith("auto"):
            config = LossConfig.parse(loss, float(weight[4:].lstrip("x") or 1.0), "auto",
                                      sensors)
        else:
            config = LossConfig.parse(loss, float(weight or 1e-5), sensors=sensors)
    except ValueError as e:
        raise ValueError(f"method '{spec}': {e}") from None
    return Method(spec, STRUCTURE_NAMES[short], config, schedule, check="check" in flags,
                  members="members" in flags, home="home" in flags)
