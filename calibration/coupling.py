"""Joints that follow another joint: an MJCF's ``<equality><joint>`` (URDF ``<mimic>`` is its
linear case, handled in ``urdf_model``).

MuJoCo's joint equality ties joint1 (the follower) to joint2 (its leader) by a quartic in
the leader's displacement from its reference pose ``qpos0``::

    q1 - ref1 = c0 + c1 d + c2 d² + c3 d³ + c4 d⁴,   d = q2 - ref2

(``mjEQ_JOINT`` in MuJoCo's ``engine_core_constraint.c``; without joint2 the follower is held
at ``ref1 + c0``). MuJoCo enforces it as a stiff soft constraint during a simulation; a model
that measures muscles at a pose applies it exactly: a follower is not a joint of its own but
a function of the driven joints, so only the independent joints are driven, sampled and
stored, and every derivative with respect to them runs through the coupling (chain rule,
dq1/dq2 = the quartic's slope), also along chains (a follower of a follower).

This module knows names and numbers only (no MuJoCo): ``mjcf`` reads the equalities,
``description`` decides which joints they make followers or hold, the MuJoCo backend and
plant apply them through ``CoupledJoints``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class JointCoupling:
    """``follower`` = ``follower_ref`` + poly(``leader`` - ``leader_ref``) (MuJoCo's rule).

    ``leader`` is None for an equality on one joint (the follower held at ref + c0).
    """

    equality: str  # the equality's name (or "equality<i>" for an unnamed one)
    follower: str
    leader: str | None
    coef: tuple[float, float, float, float, float]  # c0..c4 of MuJoCo's polycoef
    follower_ref: float  # qpos0 of the follower
    leader_ref: float  # qpos0 of the leader (0 without a leader)
    active: bool = True  # active="false": MuJoCo does not apply it unless switched on

    def value(self, leader_q: float) -> float:
        """The follower's position when its leader is at ``leader_q``."""
        d = leader_q - self.leader_ref if self.leader is not None else 0.0
        c0, c1, c2, c3, c4 = self.coef
        return self.follower_ref + c0 + d * (c1 + d * (c2 + d * (c3 + d * c4)))

    def slope(self, leader_q: float) -> float:
        """d follower / d leader at ``leader_q`` (0 without a leader)."""
        if self.leader is None:
            return 0.0
        d = leader_q - self.leader_ref
        _, c1, c2, c3, c4 = self.coef
        return c1 + d * (2 * c2 + d * (3 * c3 + d * 4 * c4))

    def formula(self) -> str:
        """The coupling in words for a listing: ``q = 0.1*elbow + ...`` about the references."""
        if self.leader is None:
            return f"held at {self.follower_ref + self.coef[0]:.4g} by equality " \
                   f"'{self.equality}'"
        d = self.leader if self.leader_ref == 0 else f"({self.leader} - {self.leader_ref:.4g})"
        terms = [f"{c:+.4g}" + ("" if k == 0 else f"*{d}" + ("" if k == 1 else f"^{k}"))
                 for k, c in enumerate(self.coef) if c != 0]
        lhs = "q" if self.follower_ref == 0 else f"q - {self.follower_ref:.4g}"
        return f"{lhs} = {' '.join(terms) or '0'}".replace("= +", "= ")


class CouplingError(ValueError):
    """The couplings cannot be resolved (a joint with two leaders, a loop); says which."""


def coupling_order(couplings: Iterable[JointCoupling]) -> list[JointCoupling]:
    """The active couplings, each after the coupling that moves its leader (so applying
    them in order moves every follower of a follower). Raises ``CouplingError`` for a joint
    that two active equalities move, or followers that lead each other in a loop."""
    by_follower: dict[str, JointCoupling] = {}
    for c in couplings:
        if not c.active:
            continue
        if c.follower in by_follower:
            raise CouplingError(
                f"joint '{c.follower}' is joint1 of two active joint equalities, "
                f"'{by_follower[c.follower].equality}' and '{c.equality}'")
        by_follower[c.follower] = c
    ordered: list[JointCoupling] = []
    placed: set[str] = set()
    for start in by_follower:
        chain: list[JointCoupling] = []
        name: str | None = start
        while name in by_follower and name not in placed:
            c = by_follower[name]
            if c in chain:
                loop = [x.follower for x in chain[chain.index(c):]]
                raise CouplingError(f"joints {', '.join(loop)} follow each other in a loop "
                                    "of joint equalities")
            chain.append(c)
            name = c.leader
        for c in reversed(chain):
            ordered.append(c)
            placed.add(c.follower)
    return ordered


def root_leader(couplings: Mapping[str, JointCoupling], joint: str) -> str | None:
    """The joint at the head of ``joint``'s chain of leaders (``joint`` itself if it follows
    nothing; None when the chain ends in an equality on one joint, which holds it)."""
    name: str | None = joint
    while name is not None and name in couplings:
        name = couplings[name].leader
    return name


class CoupledJoints:
    """The driven joints and the followers they move, as a simulator indexes them.

    ``place`` puts every follower where its coupling says, leaders first (a follower of a
    follower after its leader); ``jacobian`` is S = d(moved dofs)/d(driven joints) at a pose:
    the identity on the driven joints, each follower its leader's row times the coupling's
    slope (chain rule). Rows of S are the dofs ``columns`` (driven first, then followers).
    """

    def __init__(self, driven: Sequence[str], couplings: Sequence[JointCoupling],
                 qpos_of: Mapping[str, int], dof_of: Mapping[str, int]) -> None:
        self.couplings = tuple(couplings)
        self.n = len(driven)
        self.driven_qpos = np.array([qpos_of[j] for j in driven], dtype=int)
        self.columns = np.array([*(dof_of[j] for j in driven),
                                 *(dof_of[c.follower] for c in self.couplings)], dtype=int)
        self._follower_qpos = [qpos_of[c.follower] for c in self.couplings]
        self._leader_qpos = [qpos_of[c.leader] for c in self.couplings]  # leaders moved
        row = {j: k for k, j in enumerate(driven)}
        row.update({c.follower: self.n + k for k, c in enumerate(self.couplings)})
        self._leader_row = [row[c.leader] for c in self.couplings]

    def place(self, qpos: np.ndarray) -> None:
        """Set every follower in ``qpos`` (in place) from its leader's position."""
        for c, f, lead in zip(self.couplings, self._follower_qpos, self._leader_qpos,
                              strict=True):
            qpos[f] = c.value(float(qpos[lead]))

    def jacobian(self, qpos: np.ndarray) -> np.ndarray:
        """S (len(columns), N) at the pose ``qpos`` (followers placed)."""
        S = np.zeros((len(self.columns), self.n))
        S[:self.n] = np.eye(self.n)
        for k, (c, lead, row) in enumerate(zip(self.couplings, self._leader_qpos,
                                               self._leader_row, strict=True)):
            S[self.n + k] = c.slope(float(qpos[lead])) * S[row]
        return S


def moved_by(couplings: Mapping[str, JointCoupling], driven: Iterable[str]
             ) -> list[JointCoupling]:
    """The couplings (in the order given: leaders first) whose chain of leaders starts at a
    driven joint: the followers that move with the driven joints."""
    driven = set(driven)
    return [c for c in couplings.values() if root_leader(couplings, c.follower) in driven]
